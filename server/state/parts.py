"""A tiled job's parts as the workers move them: fan-out, claim, progress, finish, cancel.

A job whose scan has more points than its config's ``tiles.max_points`` is planned by the job's
own task (:mod:`server.worker.fanout`), which then records its parts in ``job_tiles``: the plan
(done), one row per tile (queued) and the merge (waiting). The job row stays ``running`` and
shows the sum of its parts: stage ``tiles 3/8``, progress ``PLAN_SHARE + TILES_SHARE * tiles +
MERGE_SHARE * merge``.

Every transition is one conditional UPDATE, as for jobs (:mod:`server.state.lifecycle`): a claim
moves a queued part to running and increments its ``attempts``; the claiming worker's later
writes require that attempt, so after the reaper has given the part to another worker the
stale one changes nothing. A tile's finisher commits ``done`` first and then counts the tiles
not done; the last finisher (or the reaper, when that finisher died) moves the merge from
``waiting`` to ``queued`` with ``WHERE status = 'waiting'``, so exactly one caller enqueues it.
Reaping stale parts: :mod:`server.state.part_reaper`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import case, delete, func, select, update
from sqlalchemy.orm import Session

from server.schemas import FINAL_STATUSES, TileCounts
from server.state import lifecycle, transitions
from server.state.models import Job, JobTile, utcnow

log = logging.getLogger(__name__)

#: Shares of a tiled job's progress: the plan (spilling the scan), the tiles, the merge.
PLAN_SHARE = 0.1
TILES_SHARE = 0.8
MERGE_SHARE = 0.1
#: Statuses of a part that can still be claimed (``waiting``: the merge before its tiles).
OPEN = ("waiting", "queued")


@dataclass(frozen=True)
class PartClaim:
    """A worker's hold on one attempt of a tile or of the merge of a tiled job."""

    job_id: str
    kind: str
    tile: int
    attempt: int
    job_attempt: int
    tiles: int
    filename: str
    format: str
    config: dict[str, Any]

    @property
    def name(self) -> str:
        """``tile 3/8 (job_tiles.tile 2)`` or ``merge``, for messages: counted from 1 for
        people, with the table's own index (from 0) beside it, so a log line and a row of
        ``job_tiles`` are matched without doubt."""
        if self.kind != "tile":
            return "merge"
        return f"tile {self.tile + 1}/{self.tiles} (job_tiles.tile {self.tile})"


def _part(job_id: str, kind: str, tile: int) -> Any:
    return (JobTile.job_id == job_id, JobTile.kind == kind, JobTile.tile == tile)


def _mine(part: PartClaim) -> Any:
    return (
        *_part(part.job_id, part.kind, part.tile),
        JobTile.status == "running",
        JobTile.attempts == part.attempt,
    )


def _live(job_id: str) -> Any:
    """SQL condition: the job runs and nobody asked to cancel it."""
    return (
        select(Job.id)
        .where(Job.id == job_id, Job.status == "running", Job.cancel_requested.is_(False))
        .exists()
    )


def _rowcount(result: Any) -> int:
    return int(result.rowcount)


def fan_out(
    session: Session,
    claim: lifecycle.Claim,
    tiles: int,
    *,
    worker: str,
    started_at: datetime,
    seconds: float,
) -> bool:
    """Record the parts of a planned job (plan done, tiles queued, merge waiting), in one
    transaction with the job row's progress; False when the job's attempt is no longer
    ``claim``'s or a cancel was requested (nothing is written then)."""
    now = utcnow()
    moved = session.execute(
        update(Job)
        .where(
            Job.id == claim.job_id,
            Job.status == "running",
            Job.attempts == claim.attempt,
            Job.cancel_requested.is_(False),
        )
        .values(stage=f"tiles 0/{tiles}", progress=PLAN_SHARE, heartbeat_at=now)
    )
    if not _rowcount(moved):
        session.rollback()
        return False
    session.execute(delete(JobTile).where(JobTile.job_id == claim.job_id))
    common = {"job_id": claim.job_id, "attempts": 0, "progress": 0.0}
    session.add(
        JobTile(
            **{**common, "attempts": 1, "progress": 1.0},
            kind="plan",
            tile=0,
            status="done",
            worker=worker,
            seconds=seconds,
            started_at=started_at,
            finished_at=now,
        )
    )
    session.add_all(
        JobTile(**common, kind="tile", tile=i, status="queued", queued_at=now) for i in range(tiles)
    )
    session.add(JobTile(**common, kind="merge", tile=0, status="waiting"))
    session.commit()
    return True


def claim_part(
    session: Session, job_id: str, kind: str, tile: int, worker: str
) -> PartClaim | None:
    """Move a queued part to running for ``worker``.

    Returns None when the part is not queued (any more), or when its job has ended or is being
    cancelled: such a part is marked cancelled (skipped for good).
    """
    now = utcnow()
    queued = (*_part(job_id, kind, tile), JobTile.status == "queued")
    if not transitions.move(
        session, JobTile, (*queued, _live(job_id)), transitions.claimed(JobTile, worker, now)
    ):
        session.execute(
            update(JobTile)
            .where(*_part(job_id, kind, tile), JobTile.status == "queued", ~_live(job_id))
            .values(status="cancelled", finished_at=now)
        )
        session.commit()
        return None
    part = session.get(JobTile, (job_id, kind, tile), populate_existing=True)
    job = session.get(Job, job_id, populate_existing=True)
    assert part is not None and job is not None  # just claimed
    tiles = session.scalar(
        select(func.count()).where(JobTile.job_id == job_id, JobTile.kind == "tile")
    )
    return PartClaim(
        job_id=job_id,
        kind=kind,
        tile=tile,
        attempt=part.attempts,
        job_attempt=job.attempts,
        tiles=int(tiles or 0),
        filename=job.filename,
        format=job.format,
        config=dict(job.config),
    )


def heartbeat(session: Session, part: PartClaim, worker: str) -> None:
    """Stamp the part's attempt and its worker as alive (and commit)."""
    session.execute(update(JobTile).where(*_mine(part)).values(heartbeat_at=utcnow()))
    lifecycle.stamp_worker(session, worker, part.job_id)


def cancel_requested(session: Session, part: PartClaim) -> bool:
    """Whether the part should stop: its job is being cancelled or has ended (a failed tile
    fails the job), or the attempt is no longer this worker's."""
    job = session.execute(
        select(Job.status, Job.attempts, Job.cancel_requested).where(Job.id == part.job_id)
    ).one_or_none()
    row = session.execute(
        select(JobTile.status, JobTile.attempts).where(*_part(part.job_id, part.kind, part.tile))
    ).one_or_none()
    if job is None or row is None:  # deleted
        return True
    status, attempts, flag = job
    return (
        bool(flag)
        or status != "running"
        or attempts != part.job_attempt
        or tuple(row) != ("running", part.attempt)
    )


def record_progress(
    session: Session, part: PartClaim, fraction: float, stage: str | None = None
) -> None:
    """Store the part's progress (a heartbeat too) and its job's overall progress and stage
    (``tiles d/n`` unless ``stage`` is given)."""
    session.execute(
        update(JobTile)
        .where(*_mine(part))
        .values(progress=min(1.0, max(0.0, fraction)), heartbeat_at=utcnow())
    )
    _job_progress(session, part.job_id, part.job_attempt, stage)
    session.commit()


def _job_progress(session: Session, job_id: str, job_attempt: int, stage: str | None) -> None:
    """The job row's progress and stage from its parts (never lowered: a re-queued tile starts
    over, the bar does not)."""
    rows = session.execute(
        select(JobTile.kind, JobTile.status, JobTile.progress).where(JobTile.job_id == job_id)
    ).all()
    tiles = [(status, progress) for kind, status, progress in rows if kind == "tile"]
    if not tiles:
        return
    done = sum(status == "done" for status, _ in tiles)
    tiles_share = sum(1.0 if s == "done" else p for s, p in tiles) / len(tiles)
    merge_share = sum(1.0 if s == "done" else p for k, s, p in rows if k == "merge")
    overall = min(1.0, PLAN_SHARE + TILES_SHARE * tiles_share + MERGE_SHARE * merge_share)
    session.execute(
        update(Job)
        .where(Job.id == job_id, Job.status == "running", Job.attempts == job_attempt)
        .values(
            stage=stage or f"tiles {done}/{len(tiles)}",
            progress=case((Job.progress > overall, Job.progress), else_=overall),
        )
    )


def finish_tile(session: Session, part: PartClaim, seconds: float) -> tuple[bool, bool]:
    """Mark a tile done; returns (whether the attempt was still ours, whether the caller must
    enqueue the merge: this tile was the last one and moved the merge to queued)."""
    now = utcnow()
    done = session.execute(
        update(JobTile)
        .where(*_mine(part))
        .values(status="done", progress=1.0, seconds=seconds, finished_at=now, heartbeat_at=now)
    )
    session.commit()  # visible before counting: the last of two finishers sees both
    if not _rowcount(done):
        return False, False
    merge_due = queue_merge_if_ready(session, part.job_id)
    _job_progress(session, part.job_id, part.job_attempt, None)
    session.commit()
    return True, merge_due


def queue_merge_if_ready(session: Session, job_id: str) -> bool:
    """Move the job's merge from waiting to queued when every tile is done and the job runs
    uncancelled (and commit); True for the one caller that moved it (it enqueues the merge)."""
    left = session.scalar(
        select(func.count()).where(
            JobTile.job_id == job_id, JobTile.kind == "tile", JobTile.status != "done"
        )
    )
    if left:
        return False
    moved = session.execute(
        update(JobTile)
        .where(*_part(job_id, "merge", 0), JobTile.status == "waiting", _live(job_id))
        .values(status="queued", queued_at=utcnow())
    )
    session.commit()
    return bool(_rowcount(moved))


def finish_merge(
    session: Session, part: PartClaim, *, seconds: float, points: int, timings: dict[str, float]
) -> bool:
    """Mark the merge done and the job succeeded, together; False (nothing written) when the
    merge's or the job's attempt is no longer ours."""
    now = utcnow()
    merged = session.execute(
        update(JobTile)
        .where(*_mine(part))
        .values(status="done", progress=1.0, seconds=seconds, finished_at=now, heartbeat_at=now)
    )
    succeeded = session.execute(
        update(Job)
        .where(Job.id == part.job_id, Job.status == "running", Job.attempts == part.job_attempt)
        .values(
            status="succeeded",
            error=None,
            finished_at=now,
            stage="done",
            progress=1.0,
            points=points,
            timings=timings,
        )
    )
    if not (_rowcount(merged) and _rowcount(succeeded)):
        session.rollback()
        return False
    session.commit()
    return True


def fail_part(session: Session, part: PartClaim, error: str) -> bool:
    """A part failed: it and its job fail with ``error``, the job's open parts are skipped;
    False when the part's attempt is no longer ours."""
    now = utcnow()
    failed = session.execute(
        update(JobTile).where(*_mine(part)).values(status="failed", error=error, finished_at=now)
    )
    if not _rowcount(failed):
        session.rollback()
        return False
    fail_job(session, part.job_id, error, job_attempt=part.job_attempt)
    session.commit()
    return True


def fail_job(session: Session, job_id: str, error: str, *, job_attempt: int | None = None) -> None:
    """Fail a running job and skip its open parts (no commit)."""
    same = [Job.id == job_id, Job.status == "running"]
    if job_attempt is not None:
        same.append(Job.attempts == job_attempt)
    session.execute(
        update(Job)
        .where(*same)
        .values(status="failed", error=error, finished_at=utcnow(), stage="failed")
    )
    close_open_parts(session, job_id)


def close_open_parts(session: Session, job_id: str) -> None:
    """Mark the job's waiting and queued parts cancelled (no commit)."""
    session.execute(
        update(JobTile)
        .where(JobTile.job_id == job_id, JobTile.status.in_(OPEN))
        .values(status="cancelled", finished_at=utcnow())
    )


def stop_part(session: Session, part: PartClaim) -> None:
    """Mark a part that stopped at a cancel check cancelled (if it is still ours)."""
    session.execute(
        update(JobTile).where(*_mine(part)).values(status="cancelled", finished_at=utcnow())
    )
    session.commit()


def release_part(session: Session, part: PartClaim) -> bool:
    """Put a part interrupted by its worker's shutdown back in the queued state, without
    counting the attempt; True when it is queued again (the caller re-enqueues it)."""
    values = {**transitions.released(JobTile), "queued_at": utcnow()}
    return transitions.move(session, JobTile, (*_mine(part), _live(part.job_id)), values)


def settle_cancel(session: Session, job_id: str) -> bool:
    """Finish a tiled job whose cancel was requested once none of its parts runs: its open
    parts are skipped and the job becomes cancelled. True when this call cancelled it.

    Untiled jobs and tiled jobs still planning are left to their worker.
    """
    now = utcnow()
    requested = (
        select(Job.id)
        .where(Job.id == job_id, Job.status == "running", Job.cancel_requested.is_(True))
        .exists()
    )
    session.execute(
        update(JobTile)
        .where(JobTile.job_id == job_id, JobTile.status.in_(OPEN), requested)
        .values(status="cancelled", finished_at=now)
    )
    running = (
        select(JobTile.job_id).where(JobTile.job_id == job_id, JobTile.status == "running").exists()
    )
    cancelled = session.execute(
        update(Job)
        .where(
            Job.id == job_id,
            Job.status == "running",
            Job.cancel_requested.is_(True),
            lifecycle.fanned_out(),
            ~running,
        )
        .values(
            status="cancelled", error="cancelled by request", finished_at=now, stage="cancelled"
        )
    )
    session.commit()
    return bool(_rowcount(cancelled))


def idle_and_final(session: Session, job_id: str) -> bool:
    """Whether the job has ended (or is gone) and none of its parts runs: its tile folder
    can be removed."""
    status = session.scalar(select(Job.status).where(Job.id == job_id))
    if status is not None and status not in FINAL_STATUSES:
        return False
    running = session.scalar(
        select(func.count()).where(JobTile.job_id == job_id, JobTile.status == "running")
    )
    return not running


def timings(session: Session, job_id: str) -> dict[str, float]:
    """Seconds of the plan (``prepare``), of the tiles from the first start to the last finish
    (``tiles``), summed over the tiles (``tiles_cpu``), and since the job started (``total``)."""
    rows = session.execute(
        select(JobTile.kind, JobTile.seconds, JobTile.started_at, JobTile.finished_at).where(
            JobTile.job_id == job_id, JobTile.kind.in_(("plan", "tile"))
        )
    ).all()
    out: dict[str, float] = {}
    tiles = [r for r in rows if r.kind == "tile"]
    for kind, seconds, _, _ in rows:
        if kind == "plan" and seconds is not None:
            out["prepare"] = seconds
    starts = [r.started_at for r in tiles if r.started_at is not None]
    ends = [r.finished_at for r in tiles if r.finished_at is not None]
    if starts and ends:
        out["tiles"] = (max(ends) - min(starts)).total_seconds()
    out["tiles_cpu"] = sum(r.seconds or 0.0 for r in tiles)
    started = session.scalar(select(Job.started_at).where(Job.id == job_id))
    if started is not None:
        out["total"] = (utcnow() - started).total_seconds()
    return out


def tile_counts(session: Session, job_ids: list[str]) -> dict[str, TileCounts]:
    """Total, done and running tiles of those of ``job_ids`` that were tiled."""
    if not job_ids:
        return {}
    rows = session.execute(
        select(JobTile.job_id, JobTile.status, func.count())
        .where(JobTile.job_id.in_(job_ids), JobTile.kind == "tile")
        .group_by(JobTile.job_id, JobTile.status)
    ).all()
    counts: dict[str, dict[str, int]] = {}
    for job_id, status, n in rows:
        counts.setdefault(job_id, {})[status] = int(n)
    return {
        job_id: TileCounts(
            total=sum(by.values()), done=by.get("done", 0), running=by.get("running", 0)
        )
        for job_id, by in counts.items()
    }


def delete_parts(session: Session, job_id: str) -> None:
    """Remove the job's part rows (with its job row; no commit)."""
    session.execute(delete(JobTile).where(JobTile.job_id == job_id))
