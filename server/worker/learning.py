"""A model job in a worker: the corrected jobs' versions gathered,
:func:`jointseg.adapt.learn.adapt` run over them, the checkpoint written to
``jobs/<model id>/model.pt``.

Why in the job runner's hands: a model is claimed, stamped alive, cancelled and requeued after
a worker's death exactly as a scan's job (:class:`server.worker.runner.JobRunner` calls
:func:`learn_model` for a row of kind ``model``); only the work differs.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from jointseg.exceptions import ConfigError, JobNotFound, JobStateError
from jointseg.pipeline import PipelineConfig
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from server.corrections import succeeded_job, version_file
from server.schemas import ModelSource
from server.state import lifecycle
from server.worker.context import WorkerContext

if TYPE_CHECKING:  # only for annotations: jointseg.adapt imports torch
    from jointseg.adapt.learn import Corrected

log = logging.getLogger(__name__)

#: Share of a model's progress each stage stands for: the versions' files, the network's pass
#: over them (``features``), the head's fit (``adapt``).
MODEL_WEIGHTS = {"sources": 0.1, "features": 0.3, "adapt": 0.6}


def _to_work(report_path: Path) -> np.ndarray | None:
    """The run's transform to its work frame (``frame.to_work`` of its report), if recorded."""
    try:
        body = json.loads(report_path.read_text(encoding="utf-8"))
        matrix = np.asarray(body["frame"]["to_work"], dtype=np.float64)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return matrix if matrix.shape == (4, 4) and np.isfinite(matrix).all() else None


def _corrected(context: WorkerContext, source: ModelSource) -> Corrected:
    """A source job's labels version as a corrected result (its file made once and kept, as
    a download of that version is).

    Raises
    ------
    ConfigError
        When the job was deleted (or failed) since the model was asked for.
    """
    from jointseg.adapt.learn import Corrected

    job_id = source.job_id
    try:
        succeeded_job(context.sessions, job_id, owned_by=None)
        path = version_file(context.storage, job_id, source.version, "ply")
    except (JobNotFound, JobStateError) as exc:
        raise ConfigError(f"job {job_id} can no longer be learnt from: {exc}") from None
    to_work = _to_work(context.storage.report_path(job_id))
    return Corrected(path, job_id, source.version, to_work)


def learn_model(
    context: WorkerContext,
    claim: lifecycle.Claim,
    progress: ProgressFn,
    cancel: CancelToken,
) -> dict[str, Any]:
    """Learn claim ``claim``'s model; its card's ``adapted`` section (the row's summary).

    Raises
    ------
    Cancelled
        At a cancel request or the worker's shutdown.
    ConfigError
        For sources that cannot teach it (gone, no corrected point, mixed colour).
    """
    from jointseg.adapt.head import AdaptParams
    from jointseg.adapt.learn import adapt

    sources = [ModelSource.model_validate(s) for s in claim.config.get("sources", [])]
    params = AdaptParams(**(claim.config.get("params") or {}))
    report(progress, "sources", 0.0)
    items = []
    for i, source in enumerate(sources):
        check_cancel(cancel)
        items.append(_corrected(context, source))
        report(progress, "sources", (i + 1) / len(sources))
    config = PipelineConfig()
    predictor, _ = context.predictor(config)
    out = context.storage.model_path(claim.job_id)
    out.parent.mkdir(parents=True, exist_ok=True)
    done = adapt(items, out, predictor=predictor, choice=config.network.choice(), params=params,
                 progress=progress, cancel=cancel)  # fmt: skip
    log.info("model %s learnt from %d jobs", claim.job_id, len(items))
    return dict(done.card["adapted"])
