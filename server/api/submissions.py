"""From a received upload to a queued job: config and file checked, upload stored, id enqueued.

Everything that can be refused is refused before the job row exists, so bad input leaves no job
and no file behind.
"""

from __future__ import annotations

import json
import logging
import uuid

from pydantic import ValidationError

from jointseg.exceptions import ConfigError, QueueUnavailable
from jointseg.network.registry import BACKENDS, backend, has_weights
from jointseg.pipeline import PipelineConfig
from server.api.deps import Services
from server.api.uploads import ReceivedUpload
from server.limits import check_config_limits
from server.settings import Settings
from server.state import jobs
from server.state.lifecycle import fail_queued
from server.weights import resolve_job_weights

log = logging.getLogger(__name__)


def _location(loc: tuple[int | str, ...]) -> str:
    return ".".join(str(part) for part in loc) or "(root)"


def parse_config(text: str | None, settings: Settings) -> PipelineConfig:
    """The job's PipelineConfig from the ``config`` form field (empty: defaults).

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
    if network.weights is not None:
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


def submit(services: Services, upload: ReceivedUpload, owner: str | None = None) -> jobs.JobView:
    """Check, store and enqueue an upload (blocking: run it in a worker thread); the job
    belongs to ``owner`` (the submitting key's hash; None in open mode).

    The temporary upload is removed when anything is refused.

    Raises
    ------
    ConfigError, ScanFormatError
        For a bad config or scan (no job is created).
    QueueUnavailable
        When the id cannot be enqueued (the job is then marked failed).
    """
    try:
        config = parse_config(upload.config, services.settings)
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
    try:
        services.queue.enqueue(job_id)
    except QueueUnavailable as exc:
        with services.sessions() as session:
            fail_queued(session, job_id, str(exc))
        raise
    log.info("job %s queued: %s, %d points", job_id, upload.filename, info.n_points)
    return view
