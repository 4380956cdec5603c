"""Models learnt from corrected jobs (``/v1/models``) as rows of the job table.

Why the job table: a model is learnt by the same workers from the same queue, and a worker that
dies mid-model must be noticed and its model requeued exactly as a scan's job is; a row of
``jobs`` with ``kind`` :data:`MODEL_KIND` gets the claim, heartbeats, reaper and requeue of
:mod:`server.state.lifecycle` unchanged. The jobs' own functions (:mod:`server.state.jobs`)
leave these rows out. The row's ``config`` holds the request (name, sources, params), its
``summary`` the finished model card's ``adapted`` section.

Tenants as for jobs: ``owned_by`` None sees every model, another owner's is
:class:`JobNotFound` (the same answer as an unknown id).
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import func, select, update
from sqlalchemy.orm import Session

from jointseg.exceptions import JobNotFound, JobStateError
from server.schemas import FINAL_STATUSES, ModelSource, ModelView
from server.state.models import MODEL_KIND, Job, utcnow
from server.storage import check_job_id

#: What a later job names in ``network.weights`` to use a model: ``model:<id>``.
MODEL_PREFIX = "model:"


def view(job: Job) -> ModelView:
    """A model row as the API shows it."""
    config = job.config or {}
    return ModelView(
        id=job.id,
        name=config.get("name"),
        status=job.status,  # type: ignore[arg-type]  # one of STATUSES
        stage=job.stage,
        progress=job.progress,
        error=job.error,
        attempts=job.attempts,
        sources=[ModelSource.model_validate(s) for s in config.get("sources", [])],
        params=dict(config.get("params") or {}),
        adapted=job.summary if job.status == "succeeded" else None,
        weights=f"{MODEL_PREFIX}{job.id}",
        created_at=job.created_at,
        started_at=job.started_at,
        finished_at=job.finished_at,
    )


def _row(session: Session, model_id: str, owned_by: str | None) -> Job:
    try:
        job = session.get(Job, check_job_id(model_id))
    except JobNotFound:
        job = None
    if job is None or job.kind != MODEL_KIND or (owned_by is not None and job.owner != owned_by):
        raise JobNotFound(f"model {model_id} not found")
    return job


def create_model(
    session: Session,
    *,
    model_id: str,
    name: str | None,
    sources: list[ModelSource],
    params: dict[str, Any],
    owner: str | None,
) -> ModelView:
    """Insert a queued model row and commit (the caller checked every source)."""
    job = Job(
        id=check_job_id(model_id),
        filename=(name or "model")[:255],
        format="pt",
        size_bytes=0,
        status="queued",
        progress=0.0,
        config={
            "name": name,
            "sources": [s.model_dump() for s in sources],
            "params": params,
        },
        network="randlanet",
        created_at=utcnow(),
        attempts=0,
        cancel_requested=False,
        owner=owner,
        kind=MODEL_KIND,
    )
    session.add(job)
    session.commit()
    return view(job)


def get_model(session: Session, model_id: str, *, owned_by: str | None) -> ModelView:
    """One model (of ``owned_by``, when given).

    Raises
    ------
    JobNotFound
        For an unknown or malformed id, a scan's job, or another owner's model.
    """
    return view(_row(session, model_id, owned_by))


def list_models(
    session: Session,
    *,
    status: str | None = None,
    limit: int = 50,
    offset: int = 0,
    owned_by: str | None = None,
) -> tuple[list[ModelView], int]:
    """Models newest first (with ``status``, of ``owned_by``), and how many match in all."""
    where = [Job.kind == MODEL_KIND]
    if status is not None:
        where.append(Job.status == status)
    if owned_by is not None:
        where.append(Job.owner == owned_by)
    query = select(Job).where(*where).order_by(Job.created_at.desc(), Job.id.desc())
    rows = session.scalars(query.limit(limit).offset(offset))
    total = session.scalar(select(func.count()).select_from(Job).where(*where))
    return [view(job) for job in rows], int(total or 0)


def cancel_model(session: Session, model_id: str, *, owned_by: str | None) -> ModelView:
    """Cancel a queued model at once, or ask its worker to stop (as a job's cancel).

    Raises
    ------
    JobNotFound
        As :func:`get_model`.
    JobStateError
        When the model has already finished.
    """
    job = _row(session, model_id, owned_by)
    done = session.execute(
        update(Job)
        .where(Job.id == job.id, Job.status == "queued")
        .values(status="cancelled", finished_at=utcnow(), error="cancelled by request")
    ).rowcount  # type: ignore[attr-defined]
    if not done:
        done = session.execute(
            update(Job)
            .where(Job.id == job.id, Job.status == "running")
            .values(cancel_requested=True)
        ).rowcount  # type: ignore[attr-defined]
    session.commit()
    session.refresh(job)
    if not done:
        raise JobStateError(f"model {model_id} has already finished ({job.status})")
    return view(job)


def delete_model_row(session: Session, model_id: str, *, owned_by: str | None) -> ModelView:
    """Delete a finished model's row (its file is the caller's: :meth:`Storage.delete`).

    Raises
    ------
    JobNotFound
        As :func:`get_model`.
    JobStateError
        When the model is queued or running (cancel it first).
    """
    job = _row(session, model_id, owned_by)
    if job.status not in FINAL_STATUSES:
        raise JobStateError(f"model {model_id} is {job.status}; cancel it before deleting it")
    shown = view(job)
    session.delete(job)
    session.commit()
    return shown


def usable_model(session: Session, model_id: str, *, owned_by: str | None) -> ModelView:
    """A model a job may name in ``network.weights``: one of ``owned_by``'s that succeeded.

    Raises
    ------
    JobNotFound
        As :func:`get_model`.
    JobStateError
        When it has not succeeded.
    """
    model = get_model(session, model_id, owned_by=owned_by)
    if model.status != "succeeded":
        raise JobStateError(f"model {model_id} is {model.status}, not succeeded")
    return model
