"""Processes that die together, with real `jointseg serve` processes: a SIGKILL of serve
leaves no child behind (workers, viewer, checking processes, resource tracker), the viewer's
port is free again and a restart removes the partial upload; /healthz without a key says only
whether the service is up (a worker killed mid-job: test_durability.py)."""

from __future__ import annotations

import os
import signal
import socket
import threading
import time
from pathlib import Path

import httpx
import pytest

from server.storage import Storage
from tests.support.service_process import Service, left_in_incoming, running, start_service


def _stat(pid: int) -> tuple[int, str, str] | None:
    """Parent pid, state and start time of a process (from /proc), None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2 :].split()  # after "pid (name) "
    return int(fields[1]), fields[0], fields[19]


def _descendants(pid: int) -> dict[int, str]:
    """Every process below ``pid``, by pid: its start time (to tell a reused pid apart)."""
    below: dict[int, list[int]] = {}
    started: dict[int, str] = {}
    for entry in Path("/proc").iterdir():
        stat = _stat(int(entry.name)) if entry.name.isdigit() else None
        if stat is not None:
            below.setdefault(stat[0], []).append(int(entry.name))
            started[int(entry.name)] = stat[2]
    found: dict[int, str] = {}
    todo = [pid]
    while todo:
        for child in below.get(todo.pop(), []):
            found[child] = started[child]
            todo.append(child)
    return found


def _alive(pid: int, started: str) -> bool:
    stat = _stat(pid)
    return stat is not None and stat[1] != "Z" and stat[2] == started


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _wait_viewer(port: int, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/", timeout=5).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    raise AssertionError(f"viewer not up on port {port}")


def _stalled_upload(service: Service, stop: threading.Event) -> threading.Thread:
    """An upload that sends its first bytes and then nothing, until ``stop``."""

    def send() -> None:
        host, port = service.url.removeprefix("http://").split(":")
        boundary = "stalled"
        head = (
            (
                f'--{boundary}\r\nContent-Disposition: form-data; name="file"; '
                f'filename="big.ply"\r\nContent-Type: application/octet-stream\r\n\r\n'
            ).encode()
            + b"ply\n"
            + b"0" * 20_000
        )
        request = (
            f"POST /v1/jobs HTTP/1.1\r\nHost: {host}\r\n"
            f"Content-Type: multipart/form-data; boundary={boundary}\r\n"
            f"Content-Length: 5000000\r\n\r\n"
        ).encode()
        with socket.create_connection((host, int(port)), timeout=60) as sock:
            sock.sendall(request + head)
            stop.wait(60)

    thread = threading.Thread(target=send, daemon=True)
    thread.start()
    return thread


@pytest.mark.service  # starts `jointseg serve` itself
def test_sigkill_of_serve_leaves_no_child_and_a_restart_removes_the_partial_upload(
    tmp_path,
) -> None:
    data = tmp_path / "svc"
    service = start_service(data, workers=1, viewer=True)
    stop = threading.Event()
    children: dict[int, str] = {}
    try:
        service.wait_healthy(workers=1)
        viewer_port = int(service.env["JOINTSEG_VIEWER_PORT"])
        _wait_viewer(viewer_port)
        _stalled_upload(service, stop)
        deadline = time.monotonic() + 30
        while not left_in_incoming(data):
            assert time.monotonic() < deadline, "the stalled upload never reached incoming/"
            time.sleep(0.1)
        children = _descendants(service.api.popen.pid)
        names = " ".join(_cmdline(pid) for pid in children)
        assert "resource_tracker" in names and len(children) >= 4, names  # worker, viewer, checker
        os.kill(service.api.popen.pid, signal.SIGKILL)
        service.api.popen.wait(10)
        killed = time.monotonic()
        while any(_alive(*c) for c in children.items()) and time.monotonic() - killed < 10:
            time.sleep(0.1)
        left = [_cmdline(pid) for pid, started in children.items() if _alive(pid, started)]
        assert not left, f"orphans {time.monotonic() - killed:.1f} s after the SIGKILL: {left}"
        with socket.socket() as sock:  # nobody keeps the viewer's port
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind(("127.0.0.1", viewer_port))
    finally:
        stop.set()
        for pid, started in children.items():
            if _alive(pid, started):
                os.kill(pid, signal.SIGKILL)  # only when the test failed: no orphan lives on
        service.stop()
    assert left_in_incoming(data)  # left behind by the killed API ...
    with running(data, workers=0):
        assert not left_in_incoming(data)  # ... removed by the restart


def test_healthz_without_a_key_says_only_whether_the_service_is_up(locked) -> None:
    anonymous = httpx.get(locked.url + "/healthz", timeout=30)
    assert anonymous.status_code == 200 and anonymous.json() == {"status": "degraded"}
    wrong = httpx.get(locked.url + "/healthz", headers={"Authorization": "Bearer no"}, timeout=30)
    assert wrong.json() == {"status": "degraded"}
    for key in ("key-one", "key-admin"):
        auth = {"Authorization": f"Bearer {key}"}
        full = httpx.get(locked.url + "/healthz", headers=auth, timeout=30)
        body = full.json()
        assert body["database"] and body["queue_kind"] == "sqlite" and body["workers"] == []


def test_a_second_api_on_the_same_data_keeps_the_uploads_of_the_first(tmp_path) -> None:
    first, second = Storage(tmp_path), Storage(tmp_path)
    first.claim_incoming()
    streaming = first.new_incoming(".ply")
    assert second.claim_incoming() == 0 and streaming.exists()  # first still runs
    ended = Storage(tmp_path)
    ended.claim_incoming()
    left = ended.new_incoming(".ply")
    assert ended._uploads_lock is not None
    os.close(ended._uploads_lock)  # as when its process dies: the kernel drops the lock
    assert Storage(tmp_path).claim_incoming() == 1
    assert streaming.exists() and not left.exists() and not left.parent.exists()
    first.release_incoming()
    assert not streaming.parent.exists()
    second.release_incoming()
