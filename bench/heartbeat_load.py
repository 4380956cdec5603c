"""Dead workers found in seconds, and what the short lease costs the database (issue 68).

Two parts, each on this machine's PostgreSQL (a fresh database) and Redis, with real
`jointseg serve --workers 0` and hand-started `jointseg worker` processes:

- **load**: 8 idle workers for ``--seconds`` with the old heartbeat settings (every 5 s, lease
  60 s) and with today's (every 2 s, lease 10 s), both on today's code (a heartbeat process per
  worker; each worker also runs the reaper every interval); PostgreSQL's own counters
  (``pg_stat_database``: transactions and rows written per second in that database) before
  and after.
- **kill**: two workers run a tiled floor; one is SIGKILLed in the middle of a tile; seconds
  until its tile runs again on the other worker and until ``/healthz`` stops listing it.

    .venv/bin/python bench/heartbeat_load.py [--workers 8] [--seconds 30] [--parts load,kill]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
from helpers.report import header

JOINTSEG = str(Path(sys.executable).parent / "jointseg")
ADMIN = "postgresql://postgres@127.0.0.1:5432/test"
REDIS = "redis://127.0.0.1:6379/0"
SETTINGS = {"old (5 s, lease 60 s)": (5.0, 60.0), "today (2 s, lease 10 s)": (2.0, 10.0)}


@contextmanager
def database() -> Any:
    import psycopg2

    admin = psycopg2.connect(ADMIN)
    admin.autocommit = True
    name = f"jointseg_bench_{uuid.uuid4().hex[:10]}"
    with admin.cursor() as cur:
        cur.execute(f'CREATE DATABASE "{name}"')
    try:
        yield name, f"postgresql://postgres@127.0.0.1:5432/{name}"
    finally:
        with admin.cursor() as cur:
            cur.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        admin.close()


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def service(data: Path, url: str, workers: int, interval: float, timeout: float,
            extra: dict[str, str] | None = None) -> Any:  # fmt: skip
    env = {k: v for k, v in os.environ.items() if not k.startswith("JOINTSEG_")}
    env.update({
        "JOINTSEG_DATA_DIR": str(data), "JOINTSEG_DATABASE_URL": url, "JOINTSEG_QUEUE": "redis",
        "JOINTSEG_REDIS_URL": REDIS, "JOINTSEG_QUEUE_NAME": f"bench-{uuid.uuid4().hex[:8]}",
        "JOINTSEG_HEARTBEAT_INTERVAL_S": str(interval),
        "JOINTSEG_HEARTBEAT_TIMEOUT_S": str(timeout), **(extra or {}),
    })  # fmt: skip
    port = _port()
    log = open(data / "service.log", "ab")  # noqa: SIM115
    api = [JOINTSEG, "serve", "--workers", "0", "--no-viewer", "--port", str(port)]
    procs = [subprocess.Popen(api, env=env, stdout=log, stderr=subprocess.STDOUT)]
    procs += [
        subprocess.Popen([JOINTSEG, "worker"], env=env, stdout=log, stderr=subprocess.STDOUT)
        for _ in range(workers)
    ]
    http = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            try:
                if len(http.get("/healthz").json().get("workers", [])) >= workers:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.5)
        else:
            raise SystemExit(f"{workers} workers did not come up; see {data / 'service.log'}")
        yield http
    finally:
        http.close()
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(60)
            except subprocess.TimeoutExpired:
                p.kill()
        log.close()


def stats(name: str) -> tuple[float, float]:
    import psycopg2

    with psycopg2.connect(ADMIN) as conn, conn.cursor() as cur:
        cur.execute("SELECT pg_stat_clear_snapshot()")
        cur.execute(
            "SELECT xact_commit + xact_rollback, tup_inserted + tup_updated + tup_deleted "
            "FROM pg_stat_database WHERE datname = %s",
            (name,),
        )
        row = cur.fetchone()
    return float(row[0]), float(row[1])


def load(workers: int, seconds: float) -> None:
    print(f"\n### Database load of {workers} idle workers, {seconds:.0f} s each\n")
    print("| heartbeat | transactions / s | rows written / s |")
    print("|---|---|---|")
    for label, (interval, timeout) in SETTINGS.items():
        with tempfile.TemporaryDirectory() as tmp, database() as (name, url):
            with service(Path(tmp), url, workers, interval, timeout):
                time.sleep(3 * interval)  # settled
                t0, (x0, w0) = time.monotonic(), stats(name)
                time.sleep(seconds)
                time.sleep(1.5)  # PostgreSQL flushes its counters at most every second
                (x1, w1), dt = stats(name), time.monotonic() - t0
            print(f"| {label} | {(x1 - x0) / dt:.1f} | {(w1 - w0) / dt:.1f} |", flush=True)


def kill() -> None:
    from jointseg.io import write_scan
    from jointseg.synth import make_floor

    print("\n### A hand-started worker SIGKILLed mid-tile (today's settings)\n")
    with tempfile.TemporaryDirectory() as tmp, database() as (name, url):
        data = Path(tmp)
        floor = data / "floor.ply"
        write_scan(make_floor(0, rooms=4, points=300_000), floor)
        with service(data, url, 2, *SETTINGS["today (2 s, lease 10 s)"]) as http:
            config = {"tiles": {"max_points": 80_000}, "seed": 0}
            with open(floor, "rb") as fh:
                created = http.post("/v1/jobs", files={"file": ("floor.ply", fh)},
                                    data={"config": json.dumps(config)})  # fmt: skip
            job_id = created.json()["id"]
            worker, tile = _running_tile(url, job_id)
            os.kill(int(worker.rpartition(":")[2]), signal.SIGKILL)
            killed = time.monotonic()
            again = dropped = None
            while again is None or dropped is None:
                rows = {t: (s, a, w) for t, s, a, w in _tiles(url, job_id)}
                status, attempts, owner = rows[tile]
                if again is None and attempts >= 2 and owner != worker and status != "queued":
                    again = time.monotonic() - killed
                ids = {w["id"] for w in http.get("/healthz").json().get("workers", [])}
                if dropped is None and worker not in ids:
                    dropped = time.monotonic() - killed
                if time.monotonic() - killed > 120:
                    break
                time.sleep(0.1)
            while http.get(f"/v1/jobs/{job_id}").json()["status"] in ("queued", "running"):
                time.sleep(1)
            status = http.get(f"/v1/jobs/{job_id}").json()["status"]
    print("| tile runs again after (s) | /healthz drops the worker after (s) | job |")
    print("|---|---|---|")
    print(f"| {again:.1f} | {dropped:.1f} | {status} |")


def _tiles(url: str, job_id: str) -> list[tuple[int, str, int, str | None]]:
    import psycopg2

    with psycopg2.connect(url) as conn, conn.cursor() as cur:
        cur.execute("SELECT tile, status, attempts, worker FROM job_tiles WHERE job_id = %s "
                    "AND kind = 'tile' ORDER BY tile", (job_id,))  # fmt: skip
        return [tuple(r) for r in cur.fetchall()]


def _running_tile(url: str, job_id: str) -> tuple[str, int]:
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        for tile, status, _, worker in _tiles(url, job_id):
            if status == "running" and worker:
                time.sleep(1.0)  # well inside the tile
                return worker, tile
        time.sleep(0.1)
    raise SystemExit("no tile got going")


def main() -> None:
    p = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    p.add_argument("--workers", type=int, default=8)
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--parts", default="load,kill")
    args = p.parse_args()
    header("Dead workers found in seconds, and the database load of the heartbeat")
    if "load" in args.parts:
        load(args.workers, args.seconds)
    if "kill" in args.parts:
        kill()


if __name__ == "__main__":
    main()
