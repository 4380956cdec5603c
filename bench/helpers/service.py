"""Starting the job service as a user does (`jointseg serve`), for the service benchmarks."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx

JOINTSEG = str(Path(sys.executable).parent / "jointseg")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def start_service(
    data: Path,
    workers: int,
    *,
    wait_s: float,
    key: str | None = None,
    viewer_port: int | None = None,
    **env: str,
) -> tuple[subprocess.Popen[bytes], str]:
    """`jointseg serve --workers W --no-viewer` on a free loopback port with data directory
    ``data``; no JOINTSEG_ variable of this process reaches it, only those in ``env``. Returns
    the process and its URL once ``workers`` workers report healthy (SystemExit after
    ``wait_s`` seconds). ``key``: an API key of the service (``JOINTSEG_API_KEYS``), sent to
    ``/healthz``, which tells only whether it is up without one. ``viewer_port``: run the
    viewer too, on that port."""
    headers = {"Authorization": f"Bearer {key}"} if key else None
    port = free_port()
    child_env = {k: v for k, v in os.environ.items() if not k.startswith("JOINTSEG_")}
    child_env.update(JOINTSEG_DATA_DIR=str(data), **env)
    viewer = ["--no-viewer"] if viewer_port is None else ["--viewer-port", str(viewer_port)]
    args = [JOINTSEG, "serve", "--port", str(port), "--workers", str(workers), *viewer]
    log = open(data / "serve.log", "wb")  # noqa: SIM115 - the child's
    proc = subprocess.Popen(args, env=child_env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        try:
            health = httpx.get(f"{url}/healthz", headers=headers, timeout=5).json()
            if len(health["workers"]) >= workers:
                return proc, url
        except (httpx.HTTPError, ValueError, KeyError):
            pass
        time.sleep(0.3)
    proc.kill()
    raise SystemExit(f"service did not come up; see {data / 'serve.log'}")
