"""A tiled job's parts on a real job table (SQLite and PostgreSQL): claims are exclusive and
fence stale workers, the last tile queues the merge exactly once (also when finishers race),
the reaper re-queues lost tiles and merges, a cancel settles once nothing runs, and the job's
progress and tile counts add up."""

from __future__ import annotations

import threading
from datetime import timedelta

import pytest
from sqlalchemy import select, update

from server.queue import JobQueue
from server.settings import Settings
from server.state import jobs, lifecycle, parts
from server.state.db import init_db, make_engine, make_sessions
from server.state.models import JobTile, utcnow
from server.state.part_reaper import reap_parts
from server.state.reaper import reap_and_requeue

TILES = 4


@pytest.fixture(params=["sqlite", "postgres"])
def sessions(request, tmp_path):
    if request.param == "postgres":
        settings = Settings(data_dir=tmp_path, database_url=request.getfixturevalue("postgres_url"))
    else:
        settings = Settings(data_dir=tmp_path)
    engine = make_engine(settings)
    init_db(engine)
    yield make_sessions(engine)
    engine.dispose()


def _planned(sessions, n: int = 1, count: int = TILES) -> str:
    """A job claimed and fanned out into ``count`` parts."""
    job_id = f"{n:032x}"
    with sessions() as session:
        jobs.create_job(
            session,
            job_id=job_id,
            filename="a.ply",
            fmt="ply",
            size_bytes=1,
            points=1000,
            config={},
            network="randlanet",
        )
        claim = lifecycle.claim_job(session, job_id, "planner:1")
        assert claim is not None
        now = utcnow()
        assert parts.fan_out(session, claim, count, worker="planner:1", started_at=now, seconds=1)
    return job_id


def _age(sessions, job_id: str, seconds: float, **where) -> None:
    with sessions() as session:
        session.execute(
            update(JobTile)
            .where(JobTile.job_id == job_id, *[getattr(JobTile, k) == v for k, v in where.items()])
            .values(heartbeat_at=utcnow() - timedelta(seconds=seconds))
        )
        session.commit()


def _statuses(sessions, job_id: str) -> dict[tuple[str, int], str]:
    with sessions() as session:
        rows = session.execute(
            select(JobTile.kind, JobTile.tile, JobTile.status).where(JobTile.job_id == job_id)
        ).all()
    return {(kind, tile): status for kind, tile, status in rows}


def test_tiles_then_exactly_one_merge_then_success(sessions) -> None:
    job_id = _planned(sessions)
    with sessions() as session:
        view = jobs.get_job(session, job_id)
        assert view.status == "running" and view.stage == f"tiles 0/{TILES}"
        assert view.tiles is not None and view.tiles.model_dump() == {
            "total": TILES,
            "done": 0,
            "running": 0,
        }
        assert view.progress == pytest.approx(parts.PLAN_SHARE)
        claims = [parts.claim_part(session, job_id, "tile", i, f"w:{i}") for i in range(TILES)]
        assert all(p is not None for p in claims)
        assert parts.claim_part(session, job_id, "tile", 0, "other:9") is None  # taken
        assert parts.claim_part(session, job_id, "merge", 0, "other:9") is None  # waiting
        parts.record_progress(session, claims[0], 0.5)
        view = jobs.get_job(session, job_id)
        assert view.tiles.running == TILES
        expected = parts.PLAN_SHARE + parts.TILES_SHARE * 0.5 / TILES
        assert view.progress == pytest.approx(expected)
        due = [parts.finish_tile(session, p, 1.0) for p in claims]
        assert due == [(True, False)] * (TILES - 1) + [(True, True)]
        assert parts.finish_tile(session, claims[0], 1.0) == (False, False)  # once only
        view = jobs.get_job(session, job_id)
        assert view.stage == f"tiles {TILES}/{TILES}" and view.tiles.done == TILES
        assert view.progress == pytest.approx(parts.PLAN_SHARE + parts.TILES_SHARE)
        merge = parts.claim_part(session, job_id, "merge", 0, "w:0")
        assert merge is not None and merge.name == "merge" and merge.tiles == TILES
        parts.record_progress(session, merge, 0.5, "fusion")
        assert jobs.get_job(session, job_id).stage == "fusion"
        assert parts.finish_merge(session, merge, seconds=1, points=1000, timings={"total": 1})
        view = jobs.get_job(session, job_id)
        assert parts.idle_and_final(session, job_id)
    assert view.status == "succeeded" and view.progress == 1.0 and view.tiles.done == TILES


def _finish_together(sessions, claims: list[parts.PartClaim]) -> list[bool]:
    """Finish ``claims`` from as many threads at once; whether each was told to queue the merge."""
    barrier = threading.Barrier(len(claims))
    due: list[bool] = []

    def finish(part: parts.PartClaim) -> None:
        with sessions() as session:
            barrier.wait()
            due.append(parts.finish_tile(session, part, 1.0)[1])

    threads = [threading.Thread(target=finish, args=(p,)) for p in claims]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return due


def test_racing_finishers_enqueue_the_merge_once(sessions) -> None:
    for n in range(1, 6):
        job_id = _planned(sessions, n, count=6)
        with sessions() as session:
            claims = [parts.claim_part(session, job_id, "tile", i, f"w:{i}") for i in range(6)]
        due = _finish_together(sessions, [p for p in claims if p is not None])
        assert sorted(due) == [False] * 5 + [True], due
        assert _statuses(sessions, job_id)[("merge", 0)] == "queued"


def test_a_lost_tile_is_requeued_and_its_stale_worker_fenced(sessions) -> None:
    job_id = _planned(sessions)
    with sessions() as session:
        first = parts.claim_part(session, job_id, "tile", 2, "dead:1")
        parts.record_progress(session, first, 0.7)
    _age(sessions, job_id, 10, kind="tile", tile=2)
    with sessions() as session:
        # the job row's own heartbeat is old too: the job reaper leaves a fanned-out job alone
        assert lifecycle.reap_stale(session, timeout_s=0, max_attempts=3) == []
        sweep = reap_parts(session, timeout_s=3, max_attempts=3)
        assert sweep.enqueue == [(job_id, "tile", 2)]
        second = parts.claim_part(session, job_id, "tile", 2, "alive:2")
        assert second is not None and second.attempt == 2
        assert parts.cancel_requested(session, first)
        assert not parts.cancel_requested(session, second)
        assert parts.finish_tile(session, first, 1.0) == (False, False)
        assert parts.finish_tile(session, second, 1.0) == (True, False)
        view = jobs.get_job(session, job_id)
    assert view.status == "running" and view.tiles.done == 1
    assert view.progress >= parts.PLAN_SHARE + parts.TILES_SHARE * 0.7 / TILES  # not lowered


def test_a_tile_lost_max_attempts_times_fails_the_job(sessions) -> None:
    job_id = _planned(sessions)
    for attempt in (1, 2):
        with sessions() as session:
            assert parts.claim_part(session, job_id, "tile", 1, f"w:{attempt}") is not None
        _age(sessions, job_id, 10, kind="tile", tile=1)
        with sessions() as session:
            sweep = reap_parts(session, timeout_s=3, max_attempts=2)
        assert sweep.enqueue == ([(job_id, "tile", 1)] if attempt == 1 else [])
    assert sweep.idle == [job_id]
    with sessions() as session:
        view = jobs.get_job(session, job_id)
    assert view.status == "failed"
    assert view.error.startswith("tile 2 (job_tiles.tile 1) failed: worker w:2 stopped responding")
    statuses = _statuses(sessions, job_id)
    assert statuses[("tile", 1)] == "failed" and statuses[("merge", 0)] == "cancelled"
    assert statuses[("tile", 0)] == "cancelled"  # queued tiles are skipped


def test_a_failed_tile_fails_the_job_and_stops_the_others(sessions) -> None:
    job_id = _planned(sessions)
    with sessions() as session:
        bad = parts.claim_part(session, job_id, "tile", 0, "w:1")
        other = parts.claim_part(session, job_id, "tile", 1, "w:2")
        assert parts.fail_part(session, bad, "tile 1/4 failed: too few points")
        view = jobs.get_job(session, job_id)
        assert view.status == "failed" and view.error == "tile 1/4 failed: too few points"
        assert parts.cancel_requested(session, other)  # stops at its next check
        assert not parts.idle_and_final(session, job_id)  # tile 2 still runs
        parts.stop_part(session, other)
        assert parts.idle_and_final(session, job_id)
        assert parts.claim_part(session, job_id, "tile", 2, "w:3") is None
    assert _statuses(sessions, job_id)[("tile", 2)] == "cancelled"


def test_cancel_settles_once_no_tile_runs(sessions) -> None:
    job_id = _planned(sessions)
    with sessions() as session:
        running = parts.claim_part(session, job_id, "tile", 0, "w:1")
        view = jobs.cancel_job(session, job_id)
        assert view.status == "running"  # tile 1 still runs
        assert parts.cancel_requested(session, running)
        assert parts.claim_part(session, job_id, "tile", 1, "w:2") is None  # skipped
        parts.stop_part(session, running)
        assert parts.settle_cancel(session, job_id)
        view = jobs.get_job(session, job_id)
    assert view.status == "cancelled" and view.error == "cancelled by request"
    assert set(_statuses(sessions, job_id).values()) == {"done", "cancelled"}  # plan done

    idle = _planned(sessions, 2)
    with sessions() as session:
        view = jobs.cancel_job(session, idle)  # nothing runs: cancelled at once
        assert view.status == "cancelled" and view.tiles.running == 0
        jobs.delete_job_row(session, idle)
    assert _statuses(sessions, idle) == {}


def test_the_reaper_queues_a_lost_merge_and_finishes_orphaned_cancels(sessions) -> None:
    job_id = _planned(sessions, 1, count=1)
    with sessions() as session:
        part = parts.claim_part(session, job_id, "tile", 0, "w:1")
        # the finisher dies between committing its tile and queueing the merge
        session.execute(
            update(JobTile)
            .where(JobTile.job_id == job_id, JobTile.kind == "tile")
            .values(status="done")
        )
        session.commit()
        assert reap_parts(session, timeout_s=3, max_attempts=3).enqueue == [(job_id, "merge", 0)]
        assert reap_parts(session, timeout_s=3, max_attempts=3).enqueue == []  # once
        assert part is not None

    cancelled = _planned(sessions, 2)
    with sessions() as session:
        parts.claim_part(session, cancelled, "tile", 0, "dead:1")
        jobs.cancel_job(session, cancelled)
    _age(sessions, cancelled, 10)
    with sessions() as session:
        sweep = reap_parts(session, timeout_s=3, max_attempts=3)
        assert sweep.enqueue == [] and sweep.idle == [cancelled]
        assert jobs.get_job(session, cancelled).status == "cancelled"


def test_queued_tiles_without_a_queue_entry_are_enqueued(tmp_path) -> None:
    settings = Settings(data_dir=tmp_path, heartbeat_interval_s=1, heartbeat_timeout_s=5)
    engine = make_engine(settings)
    init_db(engine)
    sessions = make_sessions(engine)
    queue = JobQueue(settings)
    try:
        job_id = _planned(sessions, 1, count=3)
        with sessions() as session:
            session.execute(
                update(JobTile)
                .where(JobTile.job_id == job_id)
                .values(queued_at=utcnow() - timedelta(seconds=60))
            )
            session.commit()
        queue.enqueue_part(job_id, "tile", 1)  # old but in the queue: not an orphan
        reap_and_requeue(sessions, queue, settings)
        assert queue.pending_parts() == {(job_id, "tile", i) for i in range(3)}
        assert queue.pending_ids() == set()  # job tasks and part tasks are told apart
        reap_and_requeue(sessions, queue, settings)
        assert len(list(queue.huey.pending())) == 3
    finally:
        queue.close()
        engine.dispose()


def test_a_shutdown_releases_a_tile_without_counting_it(sessions) -> None:
    job_id = _planned(sessions)
    with sessions() as session:
        part = parts.claim_part(session, job_id, "tile", 3, "stopping:1")
        parts.record_progress(session, part, 0.4)
        assert parts.release_part(session, part)
        assert not parts.release_part(session, part)  # once
        again = parts.claim_part(session, job_id, "tile", 3, "w:2")
    assert again is not None and again.attempt == 1


def test_the_tile_of_a_dead_worker_is_requeued_at_once(sessions) -> None:
    job_id = _planned(sessions)
    with sessions() as session:
        assert parts.claim_part(session, job_id, "tile", 0, "host:7") is not None
        assert parts.claim_part(session, job_id, "tile", 1, "host:8") is not None
        sweep = reap_parts(session, timeout_s=60, max_attempts=3, dead="host:7")
    assert sweep.enqueue == [(job_id, "tile", 0)]  # fresh heartbeats: only the dead one's
    statuses = _statuses(sessions, job_id)
    assert statuses[("tile", 0)] == "queued" and statuses[("tile", 1)] == "running"
