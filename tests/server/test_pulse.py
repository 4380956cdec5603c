"""The worker's heartbeat process (issue 68, point 1): it stamps the worker and its claim while
the worker's own threads are held up (here the GIL held for seconds by native code, as a long
native call on a big scan does), and it dies with its worker, so a killed worker's lease
expires."""

from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import time
from datetime import UTC

import pytest

from server.settings import Settings
from server.state import jobs, lifecycle
from server.state.db import init_db, make_engine, make_sessions
from server.state.models import Job, Worker
from server.worker.pulse import Pulse

INTERVAL = 0.2


@pytest.fixture
def settings(tmp_path) -> Settings:
    return Settings(data_dir=tmp_path, heartbeat_interval_s=INTERVAL, heartbeat_timeout_s=2.0)


@pytest.fixture
def sessions(settings):
    engine = make_engine(settings)
    init_db(engine)
    yield make_sessions(engine)
    engine.dispose()


def _seen(sessions, worker: str) -> float | None:
    with sessions() as session:
        row = session.get(Worker, worker)
        return None if row is None else row.seen_at.replace(tzinfo=UTC).timestamp()


def _wait_row(sessions, worker: str) -> None:
    deadline = time.monotonic() + 60
    while _seen(sessions, worker) is None:
        assert time.monotonic() < deadline, "the pulse never stamped the worker"
        time.sleep(0.05)


def test_the_pulse_beats_while_the_worker_holds_the_gil(settings, sessions) -> None:
    worker = "pulse-test:1"
    pulse = Pulse(settings, worker)
    try:
        _wait_row(sessions, worker)
        held = time.time()
        # libc's sleep called through PyDLL keeps the GIL for its whole length: no thread of
        # this process runs meanwhile
        ctypes.PyDLL(None).sleep(2)
        seen = _seen(sessions, worker)
        assert seen is not None and seen >= held + 1.5, (seen, held)
    finally:
        pulse.stop()
    assert not pulse.alive()


def test_the_pulse_stamps_the_claim_the_worker_is_on(settings, sessions) -> None:
    worker = "pulse-test:2"
    with sessions() as session:
        jobs.create_job(session, job_id="a" * 32, filename="a.ply", fmt="ply", size_bytes=1,
                        points=10, config={}, network="randlanet", owner=None)  # fmt: skip
        claim = lifecycle.claim_job(session, "a" * 32, worker)
    assert claim is not None
    pulse = Pulse(settings, worker)
    try:
        pulse.claim(claim)
        time.sleep(10 * INTERVAL)
        with sessions() as session:
            first = session.get(Job, "a" * 32).heartbeat_at
        time.sleep(5 * INTERVAL)
        with sessions() as session:
            job = session.get(Job, "a" * 32)
            row = session.get(Worker, worker)
            assert job.heartbeat_at > first  # the job's stamp moves on
            assert row.job_id == "a" * 32
        pulse.claim(None)
        time.sleep(5 * INTERVAL)
        with sessions() as session:
            assert session.get(Worker, worker).job_id is None
    finally:
        pulse.stop()


SCRIPT = """
import sys, time
from server.settings import Settings
from server.worker.pulse import Pulse
pulse = Pulse(Settings(data_dir=sys.argv[1], heartbeat_interval_s=0.2, heartbeat_timeout_s=2),
              "pulse-test:3")
print(pulse.process.pid, flush=True)
time.sleep(600)
"""


def test_the_pulse_dies_with_its_worker(tmp_path, sessions) -> None:
    worker = subprocess.Popen([sys.executable, "-c", SCRIPT, str(tmp_path)],
                              stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert worker.stdout is not None
    pid = int(worker.stdout.readline())
    _wait_row(sessions, "pulse-test:3")
    worker.send_signal(signal.SIGKILL)
    worker.wait()
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        os.kill(pid, signal.SIGKILL)
        raise AssertionError("the pulse outlived its worker")
    stamped = _seen(sessions, "pulse-test:3")
    time.sleep(1.0)
    assert _seen(sessions, "pulse-test:3") == stamped  # no more stamps
