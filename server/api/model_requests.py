"""From ``POST /v1/models`` to a queued model: every listed job checked, then one row, one id on
the queue.

Everything that can be refused is refused before the row exists (nothing is written on a
refusal), and each refusal names the field: ``jobs[1]: job ... not found`` (404, as any job of
another key), ``jobs[0]: ... is running`` (409), ``jobs[2]: no corrected points`` (422).
"""

from __future__ import annotations

import logging
import uuid

from jointseg.exceptions import ConfigError, JobNotFound, JobStateError
from server.api.deps import Services
from server.api.submissions import enqueue_new
from server.corrections import succeeded_job, user_labels
from server.schemas import ModelRequest, ModelSource, ModelView
from server.state import model_jobs

log = logging.getLogger(__name__)


def _source(services: Services, index: int, job_id: str, owned_by: str | None) -> ModelSource:
    """Job ``jobs[index]`` and its current labels version, when it may teach a model.

    Raises
    ------
    JobNotFound
        For an unknown or malformed id, or another owner's job.
    JobStateError
        When the job has not succeeded.
    ConfigError
        When its current labels version corrects no point.
    """
    field = f"jobs[{index}]"
    try:
        view = succeeded_job(services.sessions, job_id, owned_by=owned_by)
    except JobNotFound:
        raise JobNotFound(f"{field}: job {job_id} not found") from None
    except JobStateError as exc:
        raise JobStateError(f"{field}: {exc}; a model learns from succeeded jobs") from None
    version = view.labels_version
    user = user_labels(services.storage, job_id, version)
    if user is None or not (user >= 0).any():
        raise ConfigError(
            f"{field}: no corrected points (job {job_id}'s labels version {version} corrects "
            f"none; correct it first: PATCH /v1/jobs/{job_id}/labels)"
        )
    return ModelSource(job_id=job_id, version=version)


def submit_model(
    services: Services, body: ModelRequest, *, owner: str | None, owned_by: str | None
) -> ModelView:
    """Check ``body``'s jobs, then queue a model over their current labels versions
    (blocking: run it in a worker thread); it belongs to ``owner``.

    Raises
    ------
    JobNotFound, JobStateError, ConfigError
        As :func:`_source`, or a job listed twice (ConfigError); no model is created.
    QueueUnavailable
        When the id cannot be enqueued (the model is then marked failed).
    """
    for index, job_id in enumerate(body.jobs):
        if job_id in body.jobs[:index]:
            raise ConfigError(f"jobs[{index}]: job {job_id} is listed twice")
    sources = [_source(services, i, job_id, owned_by) for i, job_id in enumerate(body.jobs)]
    model_id = uuid.uuid4().hex
    with services.sessions() as session:
        view = model_jobs.create_model(
            session,
            model_id=model_id,
            name=body.name,
            sources=sources,
            params=body.params.model_dump(exclude_none=True),
            owner=owner,
        )
    enqueue_new(services, model_id)
    log.info("model %s queued: %d corrected jobs", model_id, len(sources))
    return view
