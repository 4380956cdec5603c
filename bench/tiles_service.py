"""One scan, many workers: a big synthetic floor through the job service with 1 and with 2
workers (issue 16).

The floor is made once by the command a user types (`jointseg synth --floor N --points P`, as
LAZ; rooms grow with the points as in bench/big.py). For each worker count, `jointseg serve
--workers W --no-viewer` starts on a free loopback port with a fresh data directory (SQLite
table and queue, the bundled network), the floor is uploaded with a config whose
``tiles.max_points`` is ``--tile-points``, and the job is polled until it ends. Printed per
configuration: wall time from the upload to the result, the tile count, the job's stage times
(plan, tiles from the first start to the last finish, the tiles' summed run time, merge), the
mean number of tiles running at once while the tiles ran, the peak memory of the biggest
process and of the whole service, and the peak size of the job's tile folder on the data
directory (sampled with each poll).

Worker processes get CPU cores / workers torch threads each (the service's default), so on one
machine two workers share the cores one worker had; the tiles' summed time against their wall
time says what more machines would give.

    .venv/bin/python bench/tiles_service.py [--points 4000000] [--tile-points 1000000]
        [--workers 1,2] [--nice 0] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import psutil
from helpers.inputs import cached_floor  # the same cached floors as bench/big.py
from helpers.report import header
from helpers.service import start_service


class Memory:
    """Peak resident memory of a process tree, sampled."""

    def __init__(self, pid: int) -> None:
        self.root = psutil.Process(pid)
        self.peak_one = 0
        self.peak_all = 0

    def sample(self) -> None:
        sizes = []
        for proc in [self.root, *self.root.children(recursive=True)]:
            try:
                sizes.append(proc.memory_info().rss)
            except psutil.Error:
                pass
        self.peak_one = max(self.peak_one, max(sizes, default=0))
        self.peak_all = max(self.peak_all, sum(sizes))


def folder_bytes(folder: Path) -> int:
    """Bytes of the files under ``folder`` (0 when it does not exist)."""
    total = 0
    for root, _, files in os.walk(folder):
        for name in files:
            try:
                total += (Path(root) / name).stat().st_size
            except OSError:  # renamed or removed meanwhile
                pass
    return total


def run_job(
    url: str, scan: Path, config: dict[str, Any], memory: Memory, data: Path
) -> dict[str, Any]:
    """Upload ``scan``, poll until the job ends; wall time and what the polls saw."""
    started = time.perf_counter()
    with httpx.Client(base_url=url, timeout=600) as http:
        with open(scan, "rb") as fh:
            files = {"file": (scan.name, fh)}
            response = http.post("/v1/jobs", files=files, data={"config": json.dumps(config)})
        response.raise_for_status()
        job_id = response.json()["id"]
        running: list[int] = []
        spilled = 0
        while True:
            memory.sample()
            spilled = max(spilled, folder_bytes(data / "jobs" / job_id / "tiles"))
            job = http.get(f"/v1/jobs/{job_id}").json()
            if job["tiles"] and job["stage"] and job["stage"].startswith("tiles"):
                running.append(job["tiles"]["running"])
            if job["status"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.5)
    return {
        "wall": time.perf_counter() - started,
        "job": job,
        "busy": sum(running) / len(running) if running else float("nan"),
        "spilled": spilled,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=4_000_000, help="points of the floor")
    parser.add_argument(
        "--tile-points", type=int, default=1_000_000, help="the job config's tiles.max_points"
    )
    parser.add_argument("--workers", default="1,2", help="worker counts to compare")
    parser.add_argument(
        "--nice",
        type=int,
        default=0,
        help="JOINTSEG_WORKER_NICE (the service's default 10 lets any other work on the machine "
        "take the cores first, which measures that work, not the workers)",
    )
    parser.add_argument("--keep", type=Path, help="keep the generated floor in this folder")
    args = parser.parse_args()
    header()
    counts = [int(w) for w in args.workers.split(",") if w]
    config = {"tiles": {"max_points": args.tile_points}}
    print(
        f"# one scan, many workers, {time.strftime('%F')}: {args.points:,}-point floor, "
        f"tiles of at most {args.tile_points:,} points, {os.cpu_count()} CPUs, "
        f"load average {os.getloadavg()[0]:.1f} before the run\n"
    )
    print(
        "| workers | status | tiles | wall s (upload to result) | vs 1 worker | plan s | tiles s "
        "| tiles summed s | tiles at once | merge s | peak GB (largest process / service) "
        "| tile folder peak (bytes/point) |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    first: float | None = None
    with tempfile.TemporaryDirectory(prefix="jointseg-tiles-") as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        scan = cached_floor(args.points, folder)
        for workers in counts:
            data = Path(tmp) / f"service-{workers}"
            data.mkdir()
            proc, url = start_service(
                data,
                workers,
                wait_s=300,
                JOINTSEG_LOG_LEVEL="INFO",
                JOINTSEG_WORKER_NICE=str(args.nice),
            )
            memory = Memory(proc.pid)
            try:
                row = run_job(url, scan, config, memory, data)
            finally:
                proc.send_signal(signal.SIGTERM)
                proc.wait(60)
            job, t = row["job"], row["job"]["timings"] or {}
            first = first or row["wall"]
            tiles = job["tiles"]["total"] if job["tiles"] else 1
            merge = t.get("merge", float("nan"))
            print(
                f"| {workers} | {job['status']} | {tiles} | {row['wall']:.1f} "
                f"| {first / row['wall']:.2f}x | {t.get('prepare', float('nan')):.1f} "
                f"| {t.get('tiles', float('nan')):.1f} | {t.get('tiles_cpu', float('nan')):.1f} "
                f"| {row['busy']:.2f} | {merge:.1f} "
                f"| {memory.peak_one / 1024**3:.2f} / {memory.peak_all / 1024**3:.2f} "
                f"| {row['spilled'] / 1024**3:.2f} GB ({row['spilled'] / args.points:.0f}) |",
                flush=True,
            )
            if job["status"] != "succeeded":
                print(f"  {job['error']}; see {data / 'serve.log'}", file=sys.stderr)


if __name__ == "__main__":
    main()
