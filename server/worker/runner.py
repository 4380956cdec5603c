"""Running one job id in a worker process: claim, pipeline, result files, final status.

A job whose scan has more points than its config's ``tiles.max_points`` is only planned here;
its tiles and merge are queue tasks of their own that any worker runs (:mod:`server.worker.fanout`).
A model learnt from corrections is a job row of its own kind: the same claim and final status,
its work :func:`server.worker.learning.learn_model`.

Loaded networks are kept between jobs in the process's :class:`server.worker.context.WorkerContext`
(a few configurations, least recently used dropped), so a stream of jobs with the same network
pays the loading once per process.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from jointseg.exceptions import Cancelled, ConfigError, JointsegError
from jointseg.io import probe_scan
from jointseg.pipeline import PipelineConfig, segment_file
from server.limits import check_file_span
from server.messages import one_line, public_message, without_server_paths
from server.metrics import job_finished
from server.state import lifecycle
from server.state.models import MODEL_KIND
from server.worker.context import WorkerContext
from server.worker.fanout import FanOut
from server.worker.learning import MODEL_WEIGHTS, learn_model
from server.worker.tokens import STAGE_WEIGHTS, RowCancelToken, RowProgress

log = logging.getLogger(__name__)


class JobRunner:
    """Runs one job id at a time in this process; a big scan's plan goes to the fan-out."""

    def __init__(self, context: WorkerContext) -> None:
        self.context = context
        self.settings = context.settings
        self.sessions = context.sessions
        self.storage = context.storage
        self.queue = context.queue
        self.stopping = context.stopping
        self.worker = context.worker
        self.fanout = FanOut(context)

    def __call__(self, job_id: str) -> None:
        """Run job ``job_id`` unless it was cancelled or claimed meanwhile."""
        with self.sessions() as session:
            claim = lifecycle.claim_job(session, job_id, self.worker)
        if claim is None:
            log.info("job %s: not queued any more, skipped", job_id)
            return
        self.context.current = claim
        self.context.fit_threads()
        log.info("job %s: attempt %d started by %s", job_id, claim.attempt, self.worker)
        try:
            self._run(claim)
        finally:
            self.context.current = None

    def _run(self, claim: lifecycle.Claim) -> None:
        token = RowCancelToken(self.sessions, claim, self.stopping)
        model = claim.kind == MODEL_KIND
        progress = RowProgress(self.sessions, claim, MODEL_WEIGHTS if model else STAGE_WEIGHTS)
        upload = self.storage.upload_path(claim.job_id, f".{claim.format}")
        started = time.perf_counter()
        try:
            if model:
                summary = learn_model(self.context, claim, progress, token)
                total = {"total": round(time.perf_counter() - started, 4)}
                self._finish(claim, "succeeded", summary=summary, timings=total)
                log.info("model %s succeeded in %.1f s", claim.job_id, total["total"])
                return
            done = self._segment(claim, upload, progress, token)
        except Cancelled:
            self._stopped(claim, token)
            return
        except (JointsegError, ValidationError) as exc:
            message = _failure_message(exc, upload, claim.filename)
            log.info("job %s failed: %s", claim.job_id, message)
            self._finish(claim, "failed", error=message, error_kind=type(exc).__name__)
            return
        except Exception as exc:
            log.exception("job %s: internal error", claim.job_id)
            error = f"internal error: {type(exc).__name__}: {exc}"
            self._finish(
                claim, "failed", error=one_line(without_server_paths(error)), error_kind="internal"
            )
            return
        if done is None:  # planned: its tiles and merge finish it
            return
        points, timings = done
        self._finish(claim, "succeeded", points=points, timings=timings)
        log.info("job %s succeeded: %d points in %.1f s", claim.job_id, points, timings["total"])

    def _segment(
        self, claim: lifecycle.Claim, upload: Path, progress: RowProgress, token: RowCancelToken
    ) -> tuple[int, dict[str, float]] | None:
        """A scan's job: its points and timings, or None when it was only planned (tiles)."""
        config = PipelineConfig.model_validate(claim.config)
        points = claim.points  # probed at submission; probed here only for older rows
        if points is None:
            points = probe_scan(
                upload,
                max_points=self.settings.max_points,
                max_inflation=self.settings.max_inflation,
            ).n_points
        # a scan spread over 1e18 units would fail deep in the pipeline (an allocation of
        # petabytes): refused here by one streamed pass, naming the span
        check_file_span(
            upload,
            claim.filename,
            self.settings.max_span,
            self.settings.max_points,
            max_inflation=self.settings.max_inflation,
        )
        if config.tiles.needs_tiles(points):
            self.fanout.plan(claim, config, upload, token)
            return None
        return self._pipeline(claim, config, upload, points, progress, token)

    def _pipeline(
        self,
        claim: lifecycle.Claim,
        config: PipelineConfig,
        upload: Path,
        points: int,
        progress: RowProgress,
        token: RowCancelToken,
    ) -> tuple[int, dict[str, float]]:
        progress("read", 0.0)
        progress.flush()
        predictor, load_s = self.context.predictor(config)
        done = segment_file(
            upload,
            self.storage.result_path(claim.job_id, "ply"),
            config,
            predictor=predictor,
            max_points=self.settings.max_points,
            load_s=load_s,
            names=(claim.filename, "result.ply"),
            points=points,
            progress=progress,
            cancel=token,
        )
        body = done.report
        self.storage.write_bytes(
            self.storage.report_path(claim.job_id), json.dumps(body, indent=2).encode()
        )
        return body["points"], {k: round(float(v), 4) for k, v in body["timings_s"].items()}

    def _stopped(self, claim: lifecycle.Claim, token: RowCancelToken) -> None:
        """A cancel request, or this worker's shutdown: cancelled, or back to the queue."""
        if self.stopping.is_set() and not token.requested:
            with self.sessions() as session:
                released = lifecycle.release_job(session, claim)
            if released:
                log.info("job %s: worker stopping, job re-queued", claim.job_id)
                self.storage.remove_tiles(claim.job_id)  # a plan cut short, if any
                self.queue.enqueue(claim.job_id)
                return
        self._finish(claim, "cancelled", error="cancelled by request")
        log.info("job %s cancelled", claim.job_id)

    def _finish(self, claim: lifecycle.Claim, status: str, **values: Any) -> None:
        """Store how the job ended (``error_kind``: the error's class, for the metrics)."""
        kind_of_error = values.pop("error_kind", None)
        with self.sessions() as session:
            finished = lifecycle.finish_job(session, claim, status, **values)
        if not finished:
            log.warning("job %s: attempt %d no longer ours", claim.job_id, claim.attempt)
            return
        kind = "model" if claim.kind == MODEL_KIND else "scan"
        job_finished(kind, status, values.get("timings"), kind_of_error)
        if status != "succeeded":
            self.storage.remove_tiles(claim.job_id)  # a plan that failed or was cancelled


def _failure_message(exc: BaseException, upload: Path, filename: str) -> str:
    """Why the job failed, as the client sees it (a stored config that no longer validates is
    a ConfigError; every other message names the user's file, not the stored upload)."""
    if isinstance(exc, ValidationError):
        return one_line(str(ConfigError(f"config: {exc}")))
    return public_message(exc, upload, filename)
