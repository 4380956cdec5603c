"""A job's life as the workers and the reaper move it: claim, progress, heartbeat, finish, reap.

Every transition is one conditional UPDATE on the job row. A worker's claim increments
``attempts`` and the later writes of that worker require the same ``attempts`` and status
``running``: when the reaper has meanwhile given the job to another worker (or failed it), the
stale worker's writes change nothing. Several reapers (the API's and each worker's) can run at
once for the same reason.

A job whose scan is cut into tiles leaves this module's hands once its plan is made: its row
stays ``running`` while the tiles and the merge, rows of their own (:mod:`server.state.parts`), are
claimed, stamped and reaped one by one; :func:`reap_stale` leaves such a job alone.
"""

from __future__ import annotations

import logging
import os
import socket
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

from sqlalchemy import delete, exists, func, select, update
from sqlalchemy.orm import Session

from server.state import transitions
from server.state.models import Job, JobTile, Worker, utcnow

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Claim:
    """A worker's hold on one attempt of a job."""

    job_id: str
    attempt: int
    filename: str
    format: str
    config: dict[str, Any]
    points: int | None = None
    #: The row's kind: None for a scan, :data:`server.state.models.MODEL_KIND` for a model.
    kind: str | None = None


def worker_id(pid: int | None = None) -> str:
    """This process's name in the job and worker rows: ``host:pid`` (or that of process
    ``pid`` on this host)."""
    return f"{socket.gethostname()}:{os.getpid() if pid is None else pid}"


def _attempt(claim: Claim) -> Any:
    return (Job.id == claim.job_id, Job.status == "running", Job.attempts == claim.attempt)


def claim_job(session: Session, job_id: str, worker: str) -> Claim | None:
    """Move a queued job to running for ``worker``; None when it is not queued (any more)."""
    values = {**transitions.claimed(Job, worker, utcnow()), "stage": "queued"}
    if not transitions.move(session, Job, (Job.id == job_id, Job.status == "queued"), values):
        return None
    job = session.get(Job, job_id, populate_existing=True)
    assert job is not None  # just claimed
    return Claim(
        job.id, job.attempts, job.filename, job.format, dict(job.config), job.points, job.kind
    )


def record_progress(session: Session, claim: Claim, stage: str, progress: float) -> None:
    """Store the stage and overall progress (also a heartbeat)."""
    session.execute(
        update(Job)
        .where(*_attempt(claim))
        .values(stage=stage, progress=progress, heartbeat_at=utcnow())
    )
    session.commit()


def heartbeat(session: Session, claim: Claim | None, worker: str) -> None:
    """Stamp the worker (and its running job) as alive."""
    if claim is not None:
        session.execute(update(Job).where(*_attempt(claim)).values(heartbeat_at=utcnow()))
    stamp_worker(session, worker, None if claim is None else claim.job_id)


def stamp_worker(session: Session, worker: str, job_id: str | None) -> None:
    """Stamp the worker row as alive, busy with ``job_id`` (or idle), and commit."""
    now = utcnow()
    seen = session.execute(
        update(Worker).where(Worker.id == worker).values(seen_at=now, job_id=job_id)
    )
    if not seen.rowcount:  # type: ignore[attr-defined]
        host, _, pid = worker.rpartition(":")
        session.add(
            Worker(
                id=worker, hostname=host, pid=int(pid), started_at=now, seen_at=now, job_id=job_id
            )
        )
    session.commit()


def forget_worker(session: Session, worker: str) -> None:
    """Remove the worker row of a process that stops cleanly."""
    session.execute(delete(Worker).where(Worker.id == worker))
    session.commit()


def cancel_requested(session: Session, claim: Claim) -> bool:
    """Whether someone asked to cancel this attempt (or it is no longer this worker's)."""
    row = session.execute(
        select(Job.status, Job.attempts, Job.cancel_requested).where(Job.id == claim.job_id)
    ).one_or_none()
    if row is None:  # deleted
        return True
    status, attempts, flag = row
    return bool(flag) or status != "running" or attempts != claim.attempt


def finish_job(
    session: Session,
    claim: Claim,
    status: str,
    *,
    error: str | None = None,
    points: int | None = None,
    timings: dict[str, float] | None = None,
    summary: dict[str, Any] | None = None,
) -> bool:
    """Record the end of an attempt (succeeded, failed or cancelled); False if no longer ours.
    A model's ``summary`` is written in the same UPDATE as its success."""
    values: dict[str, Any] = {
        "status": status,
        "error": error,
        "finished_at": utcnow(),
        "stage": "done" if status == "succeeded" else status,
    }
    if status == "succeeded":
        values["progress"] = 1.0
    if points is not None:
        values["points"] = points
    if timings is not None:
        values["timings"] = timings
    if summary is not None:
        values["summary"] = summary
    return transitions.move(session, Job, _attempt(claim), values)


def fail_queued(session: Session, job_id: str, error: str) -> bool:
    """Fail a job that never reached a worker (e.g. its id could not be enqueued)."""
    values = {"status": "failed", "error": error, "finished_at": utcnow(), "stage": "failed"}
    return transitions.move(session, Job, (Job.id == job_id, Job.status == "queued"), values)


def release_job(session: Session, claim: Claim) -> bool:
    """Put an attempt interrupted by its worker's shutdown back in the queue state.

    The attempt is not counted: the job did nothing wrong. Returns whether the job is queued
    again (the caller re-enqueues its id).
    """
    where = (*_attempt(claim), Job.cancel_requested.is_(False))
    return transitions.move(session, Job, where, {**transitions.released(Job), "stage": None})


def reap_stale(
    session: Session, *, timeout_s: float, max_attempts: int, dead: str | None = None
) -> list[str]:
    """Recover running jobs whose worker stopped sending heartbeats (or is known to be dead).

    A stale job is re-queued when it has attempts left, failed with the reason when not, and
    cancelled when a cancel was requested. A job fanned out into tiles is not stale as long as
    it has parts (their own reaper: :func:`server.state.part_reaper.reap_parts`). Workers not
    seen for ``timeout_s`` are forgotten.

    With ``dead`` (a worker id), only that worker's jobs are recovered, at once, and its row is
    removed: ``jointseg serve`` saw the process exit, so there is no heartbeat to wait for.

    Returns
    -------
    list of str
        Ids of the jobs put back in the queued state; the caller enqueues them.
    """
    now = utcnow()
    cutoff = now - timedelta(seconds=timeout_s)
    lost_row = transitions.lost_condition(Job, cutoff, dead)
    stale = session.execute(
        select(Job.id, Job.attempts, Job.cancel_requested, Job.worker).where(
            Job.status == "running", lost_row, ~fanned_out()
        )
    ).all()
    requeued: list[str] = []
    for job_id, attempts, cancel, worker in stale:
        same = (
            Job.id == job_id,
            Job.status == "running",
            Job.attempts == attempts,
            lost_row,
            ~fanned_out(),
        )
        lost = transitions.lost_worker(worker, timeout_s, dead=dead is not None)
        verdict = transitions.stale_verdict(
            stop=bool(cancel), attempts=attempts, max_attempts=max_attempts
        )
        if verdict == "cancelled":
            values: dict[str, Any] = {"status": "cancelled", "error": "cancelled by request"}
        elif verdict == "failed":
            values = {
                "status": "failed",
                "error": f"{lost} on attempt {attempts} of {max_attempts}",
            }
        else:
            values = {"status": "queued", "stage": None, "progress": 0.0, "worker": None}
        if values["status"] != "queued":
            values.update(finished_at=now, stage=values["status"])
        if transitions.move(session, Job, same, values, commit=False):
            log.warning("job %s: %s; now %s", job_id, lost, values["status"])
            if values["status"] == "queued":
                requeued.append(job_id)
    gone = Worker.id == dead if dead is not None else Worker.seen_at < cutoff
    session.execute(delete(Worker).where(gone))
    session.commit()
    return requeued


def fanned_out() -> Any:
    """SQL condition on a job row: its scan was cut into tiles (it has parts in job_tiles)."""
    return exists().where(JobTile.job_id == Job.id)


def live_workers(session: Session, *, timeout_s: float) -> list[Worker]:
    """Workers seen within ``timeout_s``."""
    cutoff = utcnow() - timedelta(seconds=timeout_s)
    return list(session.scalars(select(Worker).where(Worker.seen_at >= cutoff).order_by(Worker.id)))


def live_on_host(session: Session, host: str, *, timeout_s: float) -> int:
    """Workers on ``host`` seen within ``timeout_s``: the machine's share of its cores."""
    cutoff = utcnow() - timedelta(seconds=timeout_s)
    found = select(func.count()).select_from(Worker)
    return int(session.scalar(found.where(Worker.hostname == host, Worker.seen_at >= cutoff)) or 0)


def queued_before(session: Session, *, timeout_s: float) -> list[str]:
    """Ids of jobs queued for longer than ``timeout_s`` (since creation or their last run).

    Such a job is either waiting behind others or an orphan whose id never reached the queue
    (its enqueue failed, or the process re-queueing it died between commit and enqueue); the
    caller tells them apart with the queue's pending ids.
    """
    cutoff = utcnow() - timedelta(seconds=timeout_s)
    since = func.coalesce(Job.heartbeat_at, Job.created_at)
    return list(session.scalars(select(Job.id).where(Job.status == "queued", since < cutoff)).all())
