"""From a received upload to a queued job: config and file checked, upload stored, id enqueued.

Everything that can be refused is refused before the job row exists, so bad input leaves no job
and no file behind.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import uuid
from collections.abc import Callable
from typing import Any

from pydantic import ValidationError

from jointseg.exceptions import ConfigError, JobNotFound, QueueUnavailable
from jointseg.frame.params import FrameParams
from jointseg.network.registry import BACKENDS, backend, has_weights
from jointseg.pipeline import PipelineConfig
from server.api.deps import Services
from server.api.uploads import ReceivedUpload
from server.limits import check_config_limits
from server.metrics import upload_accepted
from server.model_weights import check_model_ref, model_ref
from server.settings import Settings
from server.state import jobs
from server.state.lifecycle import fail_queued
from server.weights import resolve_job_weights

log = logging.getLogger(__name__)


def _location(loc: tuple[int | str, ...]) -> str:
    return ".".join(str(part) for part in loc) or "(root)"


#: Checks a job's ``model:<id>`` weights for the submitting tenant (raises ConfigError).
ModelCheck = Callable[[str], None]


def parse_config(
    text: str | None, settings: Settings, *, check_model: ModelCheck | None = None
) -> PipelineConfig:
    """The job's PipelineConfig from the ``config`` form field (empty: defaults).

    ``network.weights`` ``model:<id>`` names a model learnt from corrections: ``check_model``
    decides whether the tenant may use it (without one it is refused as any unknown weights).

    Raises
    ------
    ConfigError
        For invalid JSON or values, naming the field (``config.fusion.ratio_threshold``), a
        number beyond the service's bounds (:mod:`server.limits`), an
        unknown network, a network without weights on this service (the job would only fail
        in the worker), or weights that are neither a pulled model nor a file in the weights
        folders (one answer whether or not the file exists; :mod:`server.weights`).
    """
    config = _validated(text)
    check_config_limits(config)
    network = config.network
    if network.name not in BACKENDS:
        raise ConfigError(
            f"config.network.name: unknown network {network.name!r}; available: "
            f"{', '.join(BACKENDS)}"
        )
    ref = model_ref(network.weights)
    if ref is not None and check_model is not None:
        check_model(ref)
    elif network.weights is not None:
        resolve_job_weights(network.weights, settings)
    elif not has_weights(network.name):
        raise ConfigError(_no_weights(network.name))
    if config.tiles.max_points > settings.max_tile_points:
        raise ConfigError(
            f"config.tiles.max_points: {config.tiles.max_points:,} is above this service's "
            f"limit of {settings.max_tile_points:,} points per tile (the memory one worker "
            f"is sized for)"
        )
    return config


def _validated(text: str | None) -> PipelineConfig:
    """The config as the client wrote it (empty: defaults), each error naming its field."""
    if text is None or not text.strip():
        return PipelineConfig()
    try:
        return PipelineConfig.model_validate_json(text)
    except ValidationError as exc:
        first = exc.errors()[0]
        if first["type"] == "json_invalid":
            raise ConfigError(f"config: not valid JSON: {first['msg']}") from exc
        problems = "; ".join(f"config.{_location(e['loc'])}: {e['msg']}" for e in exc.errors()[:5])
        raise ConfigError(problems) from exc


def _no_weights(name: str) -> str:
    """Why a job for network ``name`` cannot run here, and the command that fixes it."""
    record = backend(name)
    if record.published is not None:
        fix = f"`jointseg models pull {record.published}` on its machines installs them"
    else:
        fix = record.where_to_get
    return (
        f"config.network.name: network {name!r} has no weights installed on this service; "
        f"{fix} (or name weights in config.network.weights)"
    )


def model_check(services: Services, owned_by: str | None) -> ModelCheck:
    """The check of a job's ``model:<id>`` weights: a succeeded model of ``owned_by``."""
    return lambda ref: check_model_ref(services.sessions, ref, owned_by=owned_by)


def submit(
    services: Services,
    upload: ReceivedUpload,
    owner: str | None = None,
    *,
    owned_by: str | None = None,
) -> jobs.JobView:
    """Check, store and enqueue an upload (blocking: run it in a worker thread); the job
    belongs to ``owner`` (the submitting key's hash; None in open mode) and may use the models
    ``owned_by`` sees (the tenant's scope).

    The temporary upload is removed when anything is refused.

    Raises
    ------
    ConfigError, ScanFormatError
        For a bad config or scan (no job is created).
    QueueUnavailable
        When the id cannot be enqueued (the job is then marked failed).
    """
    try:
        check = model_check(services, owned_by)
        config = parse_config(upload.config, services.settings, check_model=check)
        # in a checking process: the API never holds a scan's points (server.api.checks)
        info = services.checker.check(upload.path, upload.filename, upload.size)
        job_id = uuid.uuid4().hex
        services.storage.commit_upload(upload.path, job_id, upload.suffix)
    except BaseException:
        upload.path.unlink(missing_ok=True)
        raise
    with services.sessions() as session:
        view = jobs.create_job(
            session,
            job_id=job_id,
            filename=upload.filename,
            fmt=upload.suffix.lstrip("."),
            size_bytes=upload.size,
            points=info.n_points,
            config=json.loads(config.model_dump_json()),
            network=config.network.name,
            owner=owner,
        )
    enqueue_new(services, job_id)
    upload_accepted(upload.size)
    log.info("job %s queued: %s, %d points", job_id, upload.filename, info.n_points)
    return view


def enqueue_new(services: Services, job_id: str) -> None:
    """Put a new job's (or model's) id on the queue; a queue that cannot take it fails the job.

    Raises
    ------
    QueueUnavailable
    """
    try:
        services.queue.enqueue(job_id)
    except QueueUnavailable as exc:
        with services.sessions() as session:
            fail_queued(session, job_id, str(exc))
        raise


def rerun_config(
    config: dict[str, Any],
    frame: dict[str, Any],
    settings: Settings,
    *,
    check_model: ModelCheck | None = None,
) -> PipelineConfig:
    """A job's stored config with ``frame``'s fields over its frame section, checked as a new
    job's config is.

    Raises
    ------
    ConfigError
        For ``frame`` that is not frame settings (``frame.up: ...``), or a config this service
        no longer runs.
    """
    try:
        FrameParams.model_validate(frame)
    except ValidationError as exc:
        problem = exc.errors()[0]
        raise ConfigError(f"frame.{_location(problem['loc'])}: {problem['msg']}") from None
    merged = {**config, "frame": {**(config.get("frame") or {}), **frame}}
    return parse_config(json.dumps(merged), settings, check_model=check_model)


def rerun(
    services: Services,
    job_id: str,
    frame: dict[str, Any],
    *,
    owner: str | None,
    owned_by: str | None,
) -> jobs.JobView:
    """A new job from job ``job_id``'s stored upload, with its config and ``frame`` over its
    frame settings (blocking); it belongs to ``owner`` and its ``rerun_of`` names the old job,
    which stays as it is (its labels versions too).

    Why: a scan put the wrong way up (or in the wrong units) is fixed by telling the frame
    stage, without uploading it again.

    Raises
    ------
    JobNotFound
        For an unknown job, another owner's (``owned_by``), or one whose upload is gone.
    ConfigError
        For bad frame settings, naming the field.
    QueueUnavailable
        When the id cannot be enqueued (the new job is then marked failed).
    """
    with services.sessions() as session:
        old = jobs.get_job(session, job_id, owned_by=owned_by)
        stored = jobs.job_config(session, job_id, owned_by=owned_by)
    check = model_check(services, owned_by)
    config = rerun_config(stored, frame, services.settings, check_model=check)
    source = services.storage.upload_path(job_id, f".{old.format}")
    if not source.is_file():
        raise JobNotFound(f"job {job_id}: its upload is gone; upload the scan again")
    new_id = uuid.uuid4().hex
    target = services.storage.upload_path(new_id, source.suffix)
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(source, target)  # the upload is never written again: one copy on disk
    except OSError:
        shutil.copyfile(source, target)
    with services.sessions() as session:
        view = jobs.create_job(
            session,
            job_id=new_id,
            filename=old.filename,
            fmt=old.format,
            size_bytes=target.stat().st_size,
            points=old.points,
            config=json.loads(config.model_dump_json()),
            network=config.network.name,
            owner=owner,
            rerun_of=job_id,
        )
    enqueue_new(services, new_id)
    log.info("job %s queued: a rerun of %s with frame %s", new_id, job_id, frame)
    return view
