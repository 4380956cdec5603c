"""Job state transitions on a real SQLite job table: claims fence stale workers, the reaper
re-queues, fails after max_attempts or honours a cancel, a shutdown releases without counting."""

from __future__ import annotations

from datetime import timedelta

import pytest
from sqlalchemy import update

from server.queue import JobQueue
from server.settings import Settings
from server.state import jobs, lifecycle
from server.state.db import init_db, make_engine, make_sessions
from server.state.models import Job, utcnow
from server.state.reaper import reap_and_requeue


@pytest.fixture
def sessions(tmp_path):
    engine = make_engine(Settings(data_dir=tmp_path))
    init_db(engine)
    yield make_sessions(engine)
    engine.dispose()


def _queued(sessions, n: int = 1) -> str:
    job_id = f"{n:032x}"
    with sessions() as session:
        jobs.create_job(
            session,
            job_id=job_id,
            filename="a.ply",
            fmt="ply",
            size_bytes=1,
            points=1,
            config={},
            network="randlanet",
        )
    return job_id


def _age_heartbeat(sessions, job_id: str, seconds: float) -> None:
    with sessions() as session:
        session.execute(
            update(Job)
            .where(Job.id == job_id)
            .values(heartbeat_at=utcnow() - timedelta(seconds=seconds))
        )
        session.commit()


def test_claim_is_exclusive_and_fences_a_stale_attempt(sessions) -> None:
    job_id = _queued(sessions)
    with sessions() as session:
        first = lifecycle.claim_job(session, job_id, "a:1")
        assert first is not None and first.attempt == 1
        assert lifecycle.claim_job(session, job_id, "b:2") is None  # already running
    _age_heartbeat(sessions, job_id, 10)
    with sessions() as session:
        assert lifecycle.reap_stale(session, timeout_s=3, max_attempts=3) == [job_id]
        second = lifecycle.claim_job(session, job_id, "b:2")
        assert second is not None and second.attempt == 2
        # the first worker comes back to life: its writes change nothing
        assert not lifecycle.finish_job(session, first, "succeeded", points=1)
        assert lifecycle.cancel_requested(session, first)
        assert not lifecycle.cancel_requested(session, second)
        assert lifecycle.finish_job(session, second, "succeeded", points=1, timings={"total": 1})
        view = jobs.get_job(session, job_id)
    assert view.status == "succeeded" and view.attempts == 2 and view.progress == 1.0


def test_reaper_fails_after_max_attempts_with_the_reason(sessions) -> None:
    job_id = _queued(sessions)
    for attempt in (1, 2):
        with sessions() as session:
            assert lifecycle.claim_job(session, job_id, f"w:{attempt}") is not None
        _age_heartbeat(sessions, job_id, 10)
        with sessions() as session:
            requeued = lifecycle.reap_stale(session, timeout_s=3, max_attempts=2)
        assert requeued == ([job_id] if attempt == 1 else [])
    with sessions() as session:
        view = jobs.get_job(session, job_id)
    assert view.status == "failed" and view.finished_at is not None
    assert "worker w:2 stopped responding (no heartbeat for 3 s) on attempt 2 of 2" in view.error


def test_fresh_heartbeats_are_left_alone_and_cancel_wins_over_requeue(sessions) -> None:
    fresh, cancelled = _queued(sessions, 1), _queued(sessions, 2)
    with sessions() as session:
        lifecycle.claim_job(session, fresh, "w:1")
        lifecycle.claim_job(session, cancelled, "w:2")
        jobs.cancel_job(session, cancelled)  # running: only the flag is set
        assert jobs.get_job(session, cancelled).status == "running"
    _age_heartbeat(sessions, cancelled, 10)
    with sessions() as session:
        assert lifecycle.reap_stale(session, timeout_s=3, max_attempts=3) == []
        assert jobs.get_job(session, fresh).status == "running"
        assert jobs.get_job(session, cancelled).status == "cancelled"


def test_release_on_shutdown_does_not_count_the_attempt(sessions) -> None:
    job_id = _queued(sessions)
    with sessions() as session:
        claim = lifecycle.claim_job(session, job_id, "w:1")
        lifecycle.record_progress(session, claim, "network", 0.4)
        assert jobs.get_job(session, job_id).progress == pytest.approx(0.4)
        assert lifecycle.release_job(session, claim)
        view = jobs.get_job(session, job_id)
    assert view.status == "queued" and view.attempts == 0 and view.progress == 0


def test_workers_are_alive_while_they_beat(sessions) -> None:
    with sessions() as session:
        lifecycle.heartbeat(session, None, "host:42")
        (worker,) = lifecycle.live_workers(session, timeout_s=3)
        assert (worker.hostname, worker.pid, worker.job_id) == ("host", 42, None)
        lifecycle.forget_worker(session, "host:42")
        assert lifecycle.live_workers(session, timeout_s=3) == []


def test_a_queued_job_without_a_queue_entry_is_enqueued_once(tmp_path, sessions) -> None:
    settings = Settings(data_dir=tmp_path, heartbeat_interval_s=1, heartbeat_timeout_s=5)
    queue = JobQueue(settings)
    try:
        orphan, waiting, fresh = _queued(sessions, 1), _queued(sessions, 2), _queued(sessions, 3)
        with sessions() as session:
            session.execute(
                update(Job)
                .where(Job.id.in_([orphan, waiting]))
                .values(created_at=utcnow() - timedelta(seconds=60))
            )
            session.commit()
        queue.enqueue(waiting)  # old but in the queue: not an orphan
        assert reap_and_requeue(sessions, queue, settings) == [orphan]
        assert queue.pending_ids() == {orphan, waiting}
        # now it is in the queue: the next sweep leaves everything alone
        assert reap_and_requeue(sessions, queue, settings) == []
        assert fresh not in queue.pending_ids()
    finally:
        queue.close()


def test_a_dead_workers_job_is_requeued_at_once_and_the_worker_forgotten(sessions) -> None:
    mine, other = _queued(sessions, 1), _queued(sessions, 2)
    with sessions() as session:
        lifecycle.claim_job(session, mine, "host:7")
        lifecycle.claim_job(session, other, "host:8")
        lifecycle.heartbeat(session, None, "host:7")
        lifecycle.heartbeat(session, None, "host:8")
        # fresh heartbeats: only the news of its death recovers host:7's job
        assert lifecycle.reap_stale(session, timeout_s=60, max_attempts=3, dead="host:7") == [mine]
        assert jobs.get_job(session, mine).status == "queued"
        assert jobs.get_job(session, other).status == "running"
        assert [w.id for w in lifecycle.live_workers(session, timeout_s=60)] == ["host:8"]
