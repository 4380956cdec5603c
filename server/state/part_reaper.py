"""Recovering the parts of tiled jobs whose workers were lost (the per-part twin of
:func:`server.state.lifecycle.reap_stale`, run by the same sweeps in the API and every worker).

- A running tile or merge without a heartbeat for ``timeout_s`` is re-queued while it has
  attempts left; after ``max_attempts`` it fails, and its job with it. A stale part of a job
  that has ended or is being cancelled is marked cancelled instead.
- A merge still waiting although every tile is done (its last finisher died between
  committing its tile and queueing the merge) is queued.
- A job whose cancel was requested is cancelled once none of its parts runs (nobody else may
  be left to do it, e.g. when every worker is gone).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from server.state import lifecycle, parts, transitions
from server.state.models import Job, JobTile, utcnow

log = logging.getLogger(__name__)

#: A part as the queue carries it: job id, kind (tile or merge), tile index (0 for the merge).
PartKey = tuple[str, str, int]


@dataclass
class Sweep:
    """What a sweep leaves for its caller: parts to enqueue, jobs whose tile folder can go."""

    enqueue: list[PartKey] = field(default_factory=list)
    idle: list[str] = field(default_factory=list)


def reap_parts(
    session: Session, *, timeout_s: float, max_attempts: int, dead: str | None = None
) -> Sweep:
    """Recover stale parts, lost merges and cancels nobody finishes (see the module doc).

    With ``dead`` (a worker id whose process exited), the parts it held are recovered at once
    instead of the parts without a heartbeat for ``timeout_s``.
    """
    sweep = Sweep()
    now = utcnow()
    cutoff = now - timedelta(seconds=timeout_s)
    lost_row = transitions.lost_condition(JobTile, cutoff, dead)
    stale = session.execute(
        select(
            JobTile.job_id,
            JobTile.kind,
            JobTile.tile,
            JobTile.attempts,
            JobTile.worker,
            Job.status,
            Job.cancel_requested,
        )
        .outerjoin(Job, Job.id == JobTile.job_id)
        .where(JobTile.status == "running", lost_row)
    ).all()
    for job_id, kind, tile, attempts, worker, job_status, cancel in stale:
        same = (
            JobTile.job_id == job_id,
            JobTile.kind == kind,
            JobTile.tile == tile,
            JobTile.status == "running",
            JobTile.attempts == attempts,
            lost_row,
        )
        name = "merge" if kind == "merge" else f"tile {tile + 1} (job_tiles.tile {tile})"
        lost = transitions.lost_worker(worker, timeout_s, dead=dead is not None)
        verdict = transitions.stale_verdict(
            stop=job_status != "running" or bool(cancel),
            attempts=attempts,
            max_attempts=max_attempts,
        )
        error = f"{name} failed: {lost} on attempt {attempts} of {max_attempts}"
        values = _verdict_values(verdict, error, now)
        if not transitions.move(session, JobTile, same, values, commit=False):
            continue
        log.warning("job %s: %s: %s; now %s", job_id, name, lost, values["status"])
        if values["status"] == "queued":
            sweep.enqueue.append((job_id, kind, tile))
        elif values["status"] == "failed":
            parts.fail_job(session, job_id, values["error"])
        session.commit()
        if values["status"] != "queued":
            _settle(session, job_id, sweep)
    session.commit()
    waiting = session.scalars(
        select(JobTile.job_id).where(JobTile.kind == "merge", JobTile.status == "waiting")
    ).all()
    for job_id in waiting:
        if parts.queue_merge_if_ready(session, job_id):
            log.warning("job %s: every tile is done but its merge was not queued; queued", job_id)
            sweep.enqueue.append((job_id, "merge", 0))
    cancelling = session.scalars(
        select(Job.id).where(
            Job.status == "running", Job.cancel_requested.is_(True), lifecycle.fanned_out()
        )
    ).all()
    for job_id in cancelling:
        _settle(session, job_id, sweep)
    return sweep


def _verdict_values(verdict: str, error: str, now: Any) -> dict[str, Any]:
    """The part's new row values for a stale verdict: cancelled, failed or queued again."""
    if verdict == "cancelled":
        return {"status": "cancelled", "finished_at": now}
    if verdict == "failed":
        return {"status": "failed", "error": error, "finished_at": now}
    return {"status": "queued", "worker": None, "progress": 0.0, "heartbeat_at": None,
            "queued_at": now}  # fmt: skip


def _settle(session: Session, job_id: str, sweep: Sweep) -> None:
    if parts.settle_cancel(session, job_id):
        log.info("job %s cancelled (no tile runs any more)", job_id)
    if parts.idle_and_final(session, job_id) and job_id not in sweep.idle:
        sweep.idle.append(job_id)


def queued_parts_before(session: Session, *, timeout_s: float) -> list[PartKey]:
    """Parts queued for longer than ``timeout_s``: waiting behind others, or orphans whose
    queue entry was lost (the caller tells them apart with the queue's pending entries)."""
    cutoff = utcnow() - timedelta(seconds=timeout_s)
    rows = session.execute(
        select(JobTile.job_id, JobTile.kind, JobTile.tile).where(
            JobTile.status == "queued", JobTile.queued_at < cutoff
        )
    ).all()
    return [(job_id, kind, tile) for job_id, kind, tile in rows]
