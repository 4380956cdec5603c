"""Job service load benchmark: 50 small jobs at once against `jointseg serve --workers 2`.

Starts the embedded service (SQLite table and queue, no viewer) on a free loopback port with a
fresh data directory, submits 50 synthetic rooms of `--points` points at the same time (the
bundled RandLA-Net weights), polls `GET /v1/jobs/{id}` from `--pollers` threads while they run,
and prints: that all succeeded, throughput, p50/p95 latency of the polls and of the uploads.
Then it streams a ~2 GiB upload (a PLY header declaring 60 M points, more than `max_points`,
followed by filler, so the API stores all of it, then refuses it and no worker spends an hour
on it) and samples the API process's resident memory during the upload: it must stay flat.

    .venv/bin/python bench/service.py [--jobs 50] [--points 5000] [--upload-gib 2] [--workers 2]
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TypedDict

import httpx
import psutil
from helpers.report import header
from helpers.service import start_service

from jointseg.io import write_scan
from jointseg.synth import make_room


def rss_mib(pid: int) -> float:
    """The process's resident memory in MiB (NaN once it is gone)."""
    try:
        return float(psutil.Process(pid).memory_info().rss) / 2**20
    except psutil.Error:
        return float("nan")


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def load_test(url: str, rooms: list[Path], jobs: int, pollers: int) -> dict[str, float]:
    post_s: list[float] = []
    get_s: list[float] = []
    ids: list[str] = []
    lock = threading.Lock()
    done = threading.Event()

    def submit(i: int) -> str:
        path = rooms[i % len(rooms)]
        with httpx.Client(base_url=url, timeout=120) as http, open(path, "rb") as fh:
            t = time.perf_counter()
            response = http.post("/v1/jobs", files={"file": (path.name, fh)})
            post_s.append(time.perf_counter() - t)
        response.raise_for_status()
        job_id = str(response.json()["id"])
        with lock:
            ids.append(job_id)
        return job_id

    def poll() -> None:
        with httpx.Client(base_url=url, timeout=30) as http:
            while not done.is_set():
                with lock:
                    job_id = random.choice(ids) if ids else None
                if job_id is None:
                    time.sleep(0.01)
                    continue
                t = time.perf_counter()
                http.get(f"/v1/jobs/{job_id}").raise_for_status()
                get_s.append(time.perf_counter() - t)
                time.sleep(0.02)

    threads = [threading.Thread(target=poll) for _ in range(pollers)]
    for thread in threads:
        thread.start()
    started = time.perf_counter()
    with ThreadPoolExecutor(jobs) as pool:
        submitted = list(pool.map(submit, range(jobs)))
    statuses: dict[str, str] = {}
    with httpx.Client(base_url=url, timeout=30) as http:
        while len(statuses) < jobs:
            for job_id in submitted:
                if job_id not in statuses:
                    status = http.get(f"/v1/jobs/{job_id}").json()["status"]
                    if status in ("succeeded", "failed", "cancelled"):
                        statuses[job_id] = status
            time.sleep(0.5)
    elapsed = time.perf_counter() - started
    done.set()
    for thread in threads:
        thread.join()
    succeeded = sum(s == "succeeded" for s in statuses.values())
    return {
        "jobs": jobs,
        "succeeded": succeeded,
        "elapsed_s": elapsed,
        "throughput": jobs / elapsed,
        "get_n": len(get_s),
        "get_p50_ms": 1000 * statistics.median(get_s),
        "get_p95_ms": 1000 * percentile(get_s, 0.95),
        "post_p50_ms": 1000 * statistics.median(post_s),
        "post_p95_ms": 1000 * percentile(post_s, 0.95),
    }


class Upload(TypedDict):
    """What a big upload met: the answer, its speed and the API's memory around it."""

    status: int
    detail: str
    seconds: float
    mib_per_s: float
    rss_before: float
    rss_max: float
    rss_after: float
    samples: int


def big_upload(url: str, api_pid: int, gib: float) -> Upload:
    """Stream a ~``gib`` GiB multipart upload while sampling the API's resident memory."""
    boundary = "benchboundary"
    header = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 60000000\n"
        b"property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    head = (
        f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="big.ply"\r\n'
        "Content-Type: application/octet-stream\r\n\r\n"
    ).encode()
    tail = f"\r\n--{boundary}--\r\n".encode()
    body_bytes = int(gib * (1 << 30)) - (1 << 20)  # stays under the default 2 GiB limit
    chunk = os.urandom(1 << 20)

    def body() -> Iterator[bytes]:
        yield head + header
        left = body_bytes - len(header)
        while left > 0:
            piece = chunk[: min(left, len(chunk))]
            left -= len(piece)
            yield piece
        yield tail

    samples: list[float] = []
    stop = threading.Event()

    def sample() -> None:
        while not stop.is_set():
            samples.append(rss_mib(api_pid))
            time.sleep(0.1)

    before = rss_mib(api_pid)
    sampler = threading.Thread(target=sample)
    sampler.start()
    started = time.perf_counter()
    response = httpx.post(
        f"{url}/v1/jobs",
        content=body(),
        headers={
            "content-type": f"multipart/form-data; boundary={boundary}",
            "content-length": str(len(head) + body_bytes + len(tail)),
        },
        timeout=httpx.Timeout(600),
    )
    elapsed = time.perf_counter() - started
    stop.set()
    sampler.join()
    return {
        "status": response.status_code,
        "detail": str(response.json().get("detail", "")),
        "seconds": elapsed,
        "mib_per_s": body_bytes / (1 << 20) / elapsed,
        "rss_before": before,
        "rss_max": max(samples),
        "rss_after": rss_mib(api_pid),
        "samples": len(samples),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=50)
    parser.add_argument("--points", type=int, default=5000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--pollers", type=int, default=4)
    parser.add_argument("--upload-gib", type=float, default=2.0)
    args = parser.parse_args()
    header()
    with tempfile.TemporaryDirectory(prefix="jointseg-bench-") as tmp:
        data = Path(tmp)
        rooms = []
        for seed in range(5):
            path = data / f"room_{seed}.ply"
            write_scan(make_room(seed, points=args.points), path)
            rooms.append(path)
        proc, url = start_service(data, args.workers, wait_s=180, JOINTSEG_LOG_LEVEL="WARNING")
        try:
            load = load_test(url, rooms, args.jobs, args.pollers)
            upload = big_upload(url, proc.pid, args.upload_gib) if args.upload_gib > 0 else None
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(60)
    print(
        f"\n`jointseg serve --workers {args.workers}`, {args.jobs} jobs of {args.points:,} "
        f"points submitted at once ({os.cpu_count()} CPU cores)\n"
    )
    print("| measure | value |")
    print("|---|---|")
    print(f"| jobs succeeded | {load['succeeded']} / {load['jobs']} |")
    print(f"| wall time, first upload to last job finished | {load['elapsed_s']:.1f} s |")
    print(f"| throughput | {load['throughput']:.2f} jobs/s |")
    print(
        f"| `GET /v1/jobs/{{id}}` latency p50 / p95 ({load['get_n']} polls) | "
        f"{load['get_p50_ms']:.1f} / {load['get_p95_ms']:.1f} ms |"
    )
    print(
        f"| `POST /v1/jobs` latency p50 / p95 | {load['post_p50_ms']:.0f} / "
        f"{load['post_p95_ms']:.0f} ms |"
    )
    if upload is not None:
        print(
            f"| {args.upload_gib:g} GiB upload: answer, time | {upload['status']} "
            f"({upload['detail'][:80]}), {upload['seconds']:.1f} s "
            f"({upload['mib_per_s']:.0f} MiB/s) |"
        )
        print(
            f"| API resident memory before / max during / after the upload | "
            f"{upload['rss_before']:.0f} / {upload['rss_max']:.0f} / "
            f"{upload['rss_after']:.0f} MiB ({upload['samples']} samples) |"
        )


if __name__ == "__main__":
    main()
