"""The rows of a job's labels versions (``label_versions``): what the API and the viewer read
and write about corrections. The per-point arrays are files (:mod:`server.corrections`).

Version 0 is the job's own result and has no row; :func:`current_version` is 0 until the first
correction. Two corrections racing for the same version meet at the unique (job, version)
pair: the second insert fails and becomes :class:`PreconditionFailed`.
"""

from __future__ import annotations

from sqlalchemy import delete, func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from jointseg.exceptions import PreconditionFailed
from server.schemas import LabelsVersion
from server.state.models import LabelVersion, utcnow


def current_version(session: Session, job_id: str) -> int:
    """The job's newest labels version (0: never corrected)."""
    query = select(func.max(LabelVersion.version)).where(LabelVersion.job_id == job_id)
    return int(session.scalar(query) or 0)


def current_versions(session: Session, job_ids: list[str]) -> dict[str, int]:
    """:func:`current_version` of several jobs in one query (jobs never corrected left out)."""
    if not job_ids:
        return {}
    query = (
        select(LabelVersion.job_id, func.max(LabelVersion.version))
        .where(LabelVersion.job_id.in_(job_ids))
        .group_by(LabelVersion.job_id)
    )
    return {job_id: int(version) for job_id, version in session.execute(query)}


def versions(session: Session, job_id: str) -> list[LabelsVersion]:
    """The job's versions 1, 2, ... (oldest first)."""
    query = select(LabelVersion).where(LabelVersion.job_id == job_id).order_by(LabelVersion.version)
    return [
        LabelsVersion(
            version=row.version,
            created_at=row.created_at,
            owner=row.owner,
            points_changed=row.points_changed,
            points_corrected=row.points_corrected,
            edits=row.edits,
        )
        for row in session.scalars(query)
    ]


def add_version(
    session: Session,
    job_id: str,
    version: int,
    *,
    owner: str | None,
    points_changed: int,
    points_corrected: int,
    edits: int,
) -> None:
    """Insert and commit version ``version`` of the job.

    Raises
    ------
    PreconditionFailed
        When the job already has this version (a concurrent correction committed first).
    """
    session.add(
        LabelVersion(
            job_id=job_id,
            version=version,
            created_at=utcnow(),
            owner=owner,
            points_changed=points_changed,
            points_corrected=points_corrected,
            edits=edits,
        )
    )
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise PreconditionFailed(
            f"job {job_id}: labels version {version} was made meanwhile by another correction"
        ) from None


def delete_versions(session: Session, job_id: str) -> int:
    """Delete the job's version rows (not committed: part of the caller's delete); how many."""
    result = session.execute(delete(LabelVersion).where(LabelVersion.job_id == job_id))
    return int(result.rowcount)  # type: ignore[attr-defined]
