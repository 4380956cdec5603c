"""Real service processes for the server tests: `jointseg serve` / `jointseg worker` as
subprocesses on free loopback ports, each with its own data directory (fixtures: conftest.py).

Jobs stay small: scans of a few thousand points from jointseg.synth and the random-weights
RandLA-Net of tests/conftest.py, passed in each job's config.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx

from jointseg.io import write_scan
from jointseg.synth import make_floor, make_room

JOINTSEG = str(Path(sys.executable).parent / "jointseg")
#: Fast heartbeats so recovery is tested in seconds, not minutes.
FAST = {
    "JOINTSEG_HEARTBEAT_INTERVAL_S": "0.5",
    "JOINTSEG_HEARTBEAT_TIMEOUT_S": "3",
    "JOINTSEG_QUEUE_POLL_S": "0.2",
    "JOINTSEG_TORCH_THREADS": "1",
    "JOINTSEG_LOG_LEVEL": "INFO",
}
FINAL = ("succeeded", "failed", "cancelled")
#: This machine's servers for the many-machines modes (.ci/run starts them).
PG_ADMIN = "postgresql://postgres@127.0.0.1:5432/test"
REDIS = "redis://127.0.0.1:6379/0"


def free_port() -> int:
    """A loopback port nobody listens on right now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def service_env(data_dir: Path, **settings: Any) -> dict[str, str]:
    """The environment of a service process: fast heartbeats, the test weights' folder as its
    weights folder, plus ``settings`` (JOINTSEG_*)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JOINTSEG_")}
    env.update(FAST)
    env["JOINTSEG_DATA_DIR"] = str(data_dir)
    weights = os.environ.get("JOINTSEG_TEST_WEIGHTS_DIR")  # the weights fixtures' folder
    if weights:
        env["JOINTSEG_WEIGHTS_DIRS"] = json.dumps([weights])
    env.update({f"JOINTSEG_{k.upper()}": str(v) for k, v in settings.items()})
    return env


@dataclass
class Proc:
    """A service subprocess with its log file."""

    popen: subprocess.Popen[bytes]
    log: Path

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 40.0) -> int:
        """Signal the process and wait for it; returns its exit code."""
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait()
                raise
        return int(self.popen.returncode)

    def text(self) -> str:
        return self.log.read_text(errors="replace")


def spawn(args: list[str], env: dict[str, str], log: Path) -> Proc:
    """Start ``jointseg ARGS`` with its output in ``log``."""
    fh = open(log, "ab")  # noqa: SIM115 - owned by the child
    popen = subprocess.Popen([JOINTSEG, *args], env=env, stdout=fh, stderr=subprocess.STDOUT)
    fh.close()
    return Proc(popen, log)


@dataclass
class Service:
    """A running API (and its workers) and how to talk to it."""

    url: str
    data_dir: Path
    api: Proc
    env: dict[str, str]
    workers: list[Proc] = field(default_factory=list)
    api_key: str | None = None

    def http(self, **kwargs: Any) -> httpx.Client:
        headers = {"Authorization": f"Bearer {self.api_key}"} if self.api_key else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=60, **kwargs)

    def wait_healthy(self, *, workers: int = 0, timeout: float = 180.0) -> dict[str, Any]:
        """Wait for /healthz to answer with at least ``workers`` live workers (asked with the
        service's key: without one a locked service says only its status)."""
        deadline = time.monotonic() + timeout
        last: Any = None
        headers = {"Authorization": f"Bearer {self.api_key}"} if self.api_key else {}
        while time.monotonic() < deadline:
            if self.api.popen.poll() is not None:
                raise AssertionError(f"service exited early:\n{self.api.text()[-3000:]}")
            try:
                last = httpx.get(f"{self.url}/healthz", headers=headers, timeout=5)
                body = last.json()
                if last.status_code == 200 and len(body["workers"]) >= workers:
                    return dict(body)
            except (httpx.HTTPError, ValueError):
                pass
            time.sleep(0.2)
        lines = [line for line in self.api.text().splitlines() if "GET /healthz" not in line]
        log = "\n".join(lines[-40:])
        raise AssertionError(f"service not healthy in {timeout} s: {last}\n{log}")

    def stop(self) -> None:
        """SIGTERM to every process at once, then wait for each."""
        procs = [*self.workers, self.api]
        for proc in procs:
            if proc.popen.poll() is None:
                proc.popen.send_signal(signal.SIGTERM)
        for proc in procs:
            proc.stop()


def start_service(
    data_dir: Path,
    *,
    workers: int = 1,
    extra_workers: int = 0,
    viewer: bool = False,
    **settings: Any,
) -> Service:
    """`jointseg serve` with ``workers`` workers, plus ``extra_workers`` `jointseg worker`
    processes (as on other machines), all sharing ``data_dir``; the viewer only on request
    (on a free port)."""
    data_dir.mkdir(parents=True, exist_ok=True)
    port = free_port()
    env = service_env(data_dir, viewer_port=free_port(), **settings)
    args = ["serve", "--host", "127.0.0.1", "--port", str(port), "--workers", str(workers)]
    api = spawn([*args, "--viewer" if viewer else "--no-viewer"], env, data_dir / "serve.log")
    service = Service(f"http://127.0.0.1:{port}", data_dir, api, env)
    for i in range(extra_workers):
        service.workers.append(spawn(["worker"], env, data_dir / f"worker-{i}.log"))
    keys = settings.get("api_keys")
    service.api_key = str(keys).split(",")[0] if keys else None
    return service


@contextmanager
def running(
    data_dir: Path, *, workers: int = 1, extra_workers: int = 0, **settings: Any
) -> Iterator[Service]:
    """:func:`start_service`, waited for until every worker announced itself, stopped after."""
    service = start_service(data_dir, workers=workers, extra_workers=extra_workers, **settings)
    try:
        service.wait_healthy(workers=workers + extra_workers)
        yield service
    finally:
        service.stop()


def left_in_incoming(data_dir: Path) -> list[Path]:
    """Uploads streaming or left behind in ``data_dir/incoming`` (each API's own folder there
    and its lock file are not uploads)."""
    found = (data_dir / "incoming").rglob("*")
    return sorted(p for p in found if p.is_file() and p.suffix != ".lock")


def scan_file(folder: Path, suffix: str = ".ply", *, points: int = 3000, seed: int = 0) -> Path:
    """A synthetic labelled room of ``points`` points, written once per name."""
    path = folder / f"room_{seed}_{points}{suffix}"
    if not path.exists():
        write_scan(make_room(seed, points=points), path)
    return path


def floor_file(folder: Path, *, points: int = 120_000, rooms: int = 4, seed: int = 0) -> Path:
    """A synthetic labelled floor (rooms along a corridor), written once per name: wide enough
    to be cut into several tiles."""
    path = folder / f"floor_{seed}_{rooms}_{points}.ply"
    if not path.exists():
        write_scan(make_floor(seed, rooms=rooms, points=points), path)
    return path


@contextmanager
def fresh_database() -> Iterator[str]:
    """A new PostgreSQL database on this machine's server, dropped afterwards (skips the test
    when the server is not reachable)."""
    import uuid

    import pytest

    psycopg2 = pytest.importorskip("psycopg2")
    try:
        admin = psycopg2.connect(PG_ADMIN, connect_timeout=3)
    except psycopg2.OperationalError as exc:
        pytest.skip(f"PostgreSQL at {PG_ADMIN} not reachable (.ci/run starts it): {exc}")
    admin.autocommit = True
    name = f"jointseg_test_{uuid.uuid4().hex[:12]}"
    with admin.cursor() as cur:
        cur.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql://postgres@127.0.0.1:5432/{name}"
    finally:
        with admin.cursor() as cur:
            cur.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        admin.close()


def wait_for(
    client: httpx.Client,
    job_id: str,
    *,
    until: tuple[str, ...] = FINAL,
    timeout: float = 120.0,
    stage: str | None = None,
) -> dict[str, Any]:
    """Poll a job until its status is in ``until`` (and, if given, its stage is ``stage``)."""
    deadline = time.monotonic() + timeout
    job: dict[str, Any] = {}
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["status"] in until and (stage is None or job["stage"] == stage):
            return job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} not {until} in {timeout} s: {job}")


def post_scan(
    client: httpx.Client,
    path: Path,
    config: dict[str, Any] | None = None,
    *,
    filename: str | None = None,
) -> httpx.Response:
    """POST /v1/jobs with ``path`` as the file (named ``filename``) and an optional config."""
    import json

    data = {"config": json.dumps(config)} if config is not None else None
    with open(path, "rb") as fh:
        return client.post("/v1/jobs", files={"file": (filename or path.name, fh)}, data=data)
