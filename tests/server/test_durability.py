"""Faults with real processes: a worker killed with SIGKILL mid-job (its job runs again within
10 s, long before the heartbeat timeout), the service stopped with SIGTERM while a job runs and
restarted with jobs queued (giving up after max_attempts: test_lifecycle.py; a SIGKILL of
`serve` itself: test_process_lifecycle.py)."""

from __future__ import annotations

import logging
import os
import signal
import time

import pytest

from server.settings import Settings
from server.state import jobs, lifecycle
from server.state.db import make_engine, make_sessions
from tests.support.service_process import post_scan, running, scan_file, start_service, wait_for

#: every test here starts `jointseg serve` itself
pytestmark = pytest.mark.service

log = logging.getLogger(__name__)
LONG = 30_000  # points: a job of several seconds with the random network on one thread


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _worker_of(service, job_id: str, timeout: float = 30.0) -> int:
    """The pid of the worker running ``job_id`` (from /healthz)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        health = service.wait_healthy()
        for worker in health["workers"]:
            if worker["job_id"] == job_id:
                return int(worker["pid"])
        time.sleep(0.1)
    raise AssertionError(f"no worker reports job {job_id}")


def _wait_started(http, job_id: str) -> dict:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        job = http.get(f"/v1/jobs/{job_id}").json()
        if job["status"] == "running" and job["progress"] > 0.1:
            return job
        assert job["status"] in ("queued", "running"), job
        time.sleep(0.1)
    raise AssertionError(f"job {job_id} did not get going: {job}")


def test_sigkill_of_a_worker_mid_job_is_requeued_at_once(tmp_path, scans, job_config) -> None:
    # a heartbeat timeout of a minute: only `serve` seeing its worker die re-queues in 10 s
    with (
        running(tmp_path / "svc", workers=1, heartbeat_timeout_s=60) as service,
        service.http() as http,
    ):
        job_id = post_scan(http, scan_file(scans, ".ply", points=LONG, seed=4), job_config)
        job_id = job_id.json()["id"]
        _wait_started(http, job_id)
        pid = _worker_of(service, job_id)
        os.kill(pid, signal.SIGKILL)
        killed_at = time.monotonic()
        left_healthz: float | None = None
        job: dict = {}
        while time.monotonic() - killed_at < 10:
            pids = [w["pid"] for w in service.wait_healthy()["workers"]]
            if left_healthz is None and pid not in pids:
                left_healthz = time.monotonic() - killed_at
            job = http.get(f"/v1/jobs/{job_id}").json()
            if job["status"] == "running" and job["attempts"] == 2:
                break
            time.sleep(0.1)
        running_again = time.monotonic() - killed_at
        assert job["status"] == "running" and job["attempts"] == 2, job  # within 10 s
        assert left_healthz is not None and left_healthz < 2, left_healthz
        log.info("worker killed: off /healthz %.1f s, job runs %.1f s", left_healthz, running_again)
        job = wait_for(http, job_id, timeout=180)
        assert job["status"] == "succeeded" and job["attempts"] == 2, job
        assert not _alive(pid)
        text = service.api.text()
        assert f"worker {lifecycle.worker_id(pid)} died" in text and "restarting worker" in text
        result = service.data_dir / "jobs" / job_id / "result.ply"
        assert result.is_file()
        assert not [p for p in result.parent.iterdir() if p.name.startswith(".")]  # no temp file


def test_sigterm_requeues_the_running_job_and_a_restart_runs_every_queued_job(
    tmp_path, scans, job_config
) -> None:
    data = tmp_path / "svc"
    service = start_service(data, workers=1)
    try:
        service.wait_healthy(workers=1)
        with service.http() as http:
            long_id = post_scan(http, scan_file(scans, ".ply", points=LONG, seed=4), job_config)
            long_id = long_id.json()["id"]
            small = [
                post_scan(http, scan_file(scans, ".ply", seed=s), job_config).json()["id"]
                for s in (10, 11, 12)
            ]
            _wait_started(http, long_id)
            pids = [w["pid"] for w in service.wait_healthy(workers=1)["workers"]]
        started = time.monotonic()
        assert service.api.stop(signal.SIGTERM) == 0
        assert time.monotonic() - started < 30
        assert not any(_alive(pid) for pid in pids)  # workers stopped with the API
    finally:
        service.stop()
    assert "job re-queued" in service.api.text()

    # the job table on disk: every job is still there, queued, the interrupted one not counted
    engine = make_engine(Settings(data_dir=data))
    with make_sessions(engine)() as session:
        queued = jobs.list_jobs(session)
    engine.dispose()
    assert len(queued) == 4 and {j.status for j in queued} == {"queued"}
    assert {j.id: j.attempts for j in queued}[long_id] == 0
    # restarted: the API answers for the queued jobs and the worker runs all of them
    with running(data, workers=1) as again, again.http() as http:
        done = [wait_for(http, job_id, timeout=180) for job_id in [long_id, *small]]
    assert all(j["status"] == "succeeded" and j["attempts"] == 1 for j in done), done
