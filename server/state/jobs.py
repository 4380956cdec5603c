"""What the routes (and the viewer) do with jobs: create, list, look up, cancel, delete.

Functions take a SQLAlchemy session and return :class:`server.schemas.JobView`, the pydantic
model the API answers with, so callers never hold ORM objects. A tiled job's view carries its
tiles' counts (from ``job_tiles``, :mod:`server.state.parts`).

Models learnt from corrections are rows of the same table (:mod:`server.state.model_jobs`),
left out of everything here: a model's id is no job's.

Tenants: every lookup takes ``owned_by``, the owner whose jobs the caller may see
(:attr:`server.api.auth.Tenant.scope`; None: every job). Another owner's job raises the same
:class:`JobNotFound` as a job that does not exist, so its existence does not leak.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import func, or_, select, update
from sqlalchemy.orm import Session

from jointseg.exceptions import JobNotFound, JobStateError
from server.schemas import FINAL_STATUSES, JobStatus, JobView, TileCounts
from server.state import labels, parts
from server.state.models import MODEL_KIND, Job, utcnow
from server.storage import check_job_id

__all__ = [
    "JobNotFound",
    "JobStatus",
    "JobView",
    "cancel_job",
    "count_jobs",
    "create_job",
    "delete_job_row",
    "get_job",
    "job_config",
    "list_jobs",
]


def _view(job: Job, counts: TileCounts | None = None, labels_version: int = 0) -> JobView:
    view = JobView.model_validate(job)
    update: dict[str, object] = {
        "quality": (job.config or {}).get("quality", "standard"),
        "labels_version": labels_version,
    }
    if counts is not None:
        update["tiles"] = counts
    return view.model_copy(update=update)


def _views(session: Session, rows: list[Job]) -> list[JobView]:
    ids = [job.id for job in rows]
    counts = parts.tile_counts(session, ids)
    versions = labels.current_versions(session, ids)
    return [_view(job, counts.get(job.id), versions.get(job.id, 0)) for job in rows]


def scan_jobs() -> Any:
    """SQL condition on a job row: a scan's job, not a model (:data:`MODEL_KIND`)."""
    return or_(Job.kind.is_(None), Job.kind != MODEL_KIND)


def _row(session: Session, job_id: str, owned_by: str | None = None) -> Job:
    job = session.get(Job, check_job_id(job_id))
    if job is None or job.kind == MODEL_KIND or (owned_by is not None and job.owner != owned_by):
        raise JobNotFound(f"job {job_id} not found")
    return job


def create_job(
    session: Session,
    *,
    job_id: str,
    filename: str,
    fmt: str,
    size_bytes: int,
    points: int | None,
    config: dict[str, Any],
    network: str,
    owner: str | None = None,
    rerun_of: str | None = None,
) -> JobView:
    """Insert a queued job (its upload already stored) and commit; ``owner`` is the submitting
    key's hash (None in open mode), ``rerun_of`` the job it re-runs."""
    job = Job(
        id=check_job_id(job_id),
        filename=filename,
        format=fmt,
        size_bytes=size_bytes,
        status="queued",
        progress=0.0,
        points=points,
        config=config,
        network=network,
        created_at=utcnow(),
        attempts=0,
        cancel_requested=False,
        owner=owner,
        rerun_of=rerun_of,
    )
    session.add(job)
    session.commit()
    return _view(job)


def get_job(session: Session, job_id: str, *, owned_by: str | None = None) -> JobView:
    """One job (of ``owned_by``, when given).

    Raises
    ------
    JobNotFound
        For an unknown (or malformed) id, or another owner's job.
    """
    # the tile counts first, then the row: a plan records its tiles and the row's stage in one
    # commit, so a row read after the counts is never older than them (no "read" stage beside
    # tile counts under READ COMMITTED)
    counts = parts.tile_counts(session, [check_job_id(job_id)])
    job = _row(session, job_id, owned_by)
    return _view(job, counts.get(job.id), labels.current_version(session, job.id))


def job_config(session: Session, job_id: str, *, owned_by: str | None = None) -> dict[str, Any]:
    """The config a job was submitted with (as stored: every field, presets applied).

    Raises
    ------
    JobNotFound
        For an unknown id or another owner's job.
    """
    return dict(_row(session, job_id, owned_by).config or {})


def list_jobs(
    session: Session,
    *,
    status: str | None = None,
    limit: int = 50,
    offset: int = 0,
    owned_by: str | None = None,
) -> list[JobView]:
    """Jobs newest first, optionally only those with ``status`` (and of ``owned_by``)."""
    query = (
        select(Job)
        .where(scan_jobs())
        .order_by(Job.created_at.desc(), Job.id.desc())
        .limit(limit)
        .offset(offset)
    )
    if status is not None:
        query = query.where(Job.status == status)
    if owned_by is not None:
        query = query.where(Job.owner == owned_by)
    return _views(session, list(session.scalars(query)))


def count_jobs(session: Session, *, status: str | None = None, owned_by: str | None = None) -> int:
    """How many jobs (with ``status``, of ``owned_by``) exist, for pagination."""
    query = select(func.count()).select_from(Job).where(scan_jobs())
    if status is not None:
        query = query.where(Job.status == status)
    if owned_by is not None:
        query = query.where(Job.owner == owned_by)
    return int(session.scalar(query) or 0)


def cancel_job(session: Session, job_id: str, *, owned_by: str | None = None) -> JobView:
    """Cancel a queued job at once, or ask a running job's worker to stop.

    A queued job becomes ``cancelled`` immediately (its worker will skip it); a running one gets
    its cancel flag, which the worker reads within about half a second and then marks the job
    cancelled. A tiled job none of whose tiles runs right now is cancelled at once (its queued
    tiles are skipped); otherwise its running tiles stop at their next cancel check and the
    last to stop marks it cancelled. The caller removes a cancelled job's tile folder.

    Raises
    ------
    JobNotFound
        For an unknown id or another owner's job.
    JobStateError
        When the job has already finished.
    """
    job = _row(session, job_id, owned_by)
    queued = session.execute(
        update(Job)
        .where(Job.id == job.id, Job.status == "queued")
        .values(status="cancelled", finished_at=utcnow(), error="cancelled by request")
    )
    changed = queued.rowcount  # type: ignore[attr-defined]
    if not changed:
        running = session.execute(
            update(Job)
            .where(Job.id == job.id, Job.status == "running")
            .values(cancel_requested=True)
        )
        changed = running.rowcount  # type: ignore[attr-defined]
    session.commit()
    if changed:
        parts.settle_cancel(session, job.id)
    session.refresh(job)
    if not changed:
        raise JobStateError(f"job {job_id} has already finished ({job.status})")
    return _views(session, [job])[0]


def delete_job_row(session: Session, job_id: str, *, owned_by: str | None = None) -> JobView:
    """Delete a finished job's row (its files are the caller's: :meth:`Storage.delete`).

    Raises
    ------
    JobNotFound
        For an unknown id or another owner's job.
    JobStateError
        When the job is queued or running (cancel it first).
    """
    job = _row(session, job_id, owned_by)
    if job.status not in FINAL_STATUSES:
        raise JobStateError(f"job {job_id} is {job.status}; cancel it before deleting it")
    view = _views(session, [job])[0]
    session.delete(job)
    parts.delete_parts(session, job.id)
    labels.delete_versions(session, job.id)
    session.commit()
    return view
