"""One scan, many workers: a big job's plan, tile and merge tasks in a worker process.

A job whose upload has more points than its config's ``tiles.max_points`` is run in three
steps (the library's :mod:`jointseg.pipeline.tiled`: ``plan``, ``run_tile``, ``finish``), all
through the shared data directory::

    run_job(id)        the job's claim: spill the upload into jobs/<id>/tiles/<attempt>/,
                       plan the tiles, record them (server.state.parts.fan_out), enqueue each tile
    run_tile(id, i)    any worker: claim tile i, run network + geometry on it, write its result
                       file; the last tile's finisher queues the merge (exactly once)
    merge_tiles(id)    any worker: join the tiles, vote, write result.ply and report.json,
                       mark the job succeeded, remove the tile folder

A tile whose worker dies is re-queued by the reaper (:mod:`server.state.part_reaper`) and run again
by any worker; a tile that already has its result file (the library writes it atomically and
deterministically) is not run twice. A cancel stops the running tiles at their next cancel
check and skips the queued ones; a failed tile fails the job.
"""

from __future__ import annotations

import json
import logging
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import ValidationError

from jointseg.exceptions import Cancelled, ConfigError, JointsegError, QueueUnavailable
from jointseg.pipeline import PipelineConfig
from server.messages import one_line, public_message, without_server_paths
from server.metrics import job_finished
from server.state import lifecycle, parts
from server.state.models import Job, utcnow
from server.worker.tokens import (
    MERGE_WEIGHTS,
    PLAN_WEIGHTS,
    TILE_WEIGHTS,
    PartProgress,
    RowCancelToken,
    RowProgress,
)

if TYPE_CHECKING:
    from server.worker.context import WorkerContext

log = logging.getLogger(__name__)


class FanOut:
    """The tiled jobs' tasks of one worker process, sharing its context's loaded networks."""

    def __init__(self, context: WorkerContext) -> None:
        self.context = context
        self.sessions = context.sessions
        self.storage = context.storage
        self.settings = context.settings

    # -- the plan: in the job's own task, under its claim ------------------------------------

    def plan(
        self,
        claim: lifecycle.Claim,
        config: PipelineConfig,
        upload: Path,
        token: RowCancelToken,
    ) -> None:
        """Spill and plan the scan, record the tiles and enqueue them (the job stays running).

        Raises
        ------
        Cancelled
            When the job was cancelled (or this worker is stopping) before it fanned out.
        JointsegError
            When the scan cannot be read or planned.
        """
        # deferred: the tile store loads the geometry (open3d) when it plans
        from jointseg.pipeline import tiled

        work = self.storage.tiles_dir(claim.job_id, claim.attempt)
        _clear(work.parent)  # what earlier (interrupted) attempts left
        progress = RowProgress(self.sessions, claim, PLAN_WEIGHTS)
        progress("read", 0.0)
        progress.flush()
        started_at, started = utcnow(), time.perf_counter()
        # the network takes part in the plan (a crop plan shared by the tiles, so the tiles
        # together label the scan as one run would)
        predictor, _ = self.context.predictor(config)
        plan = tiled.plan(
            upload,
            work,
            config,
            name=claim.filename,
            predictor=predictor,
            max_points=self.settings.max_points,
            progress=progress,
            cancel=token,
        )
        seconds = time.perf_counter() - started
        with self.sessions() as session:
            ours = parts.fan_out(
                session,
                claim,
                len(plan.tiles),
                worker=self.context.worker,
                started_at=started_at,
                seconds=seconds,
            )
            job = None if ours else session.get(Job, claim.job_id)
            # still this attempt, but a cancel came while planning: the runner cancels the job
            cancelled = (
                job is not None
                and (job.status, job.attempts) == ("running", claim.attempt)
                and job.cancel_requested
            )
        if cancelled:
            raise Cancelled("cancelled by request")
        if not ours:
            log.warning(
                "job %s: attempt %d no longer ours after its plan", claim.job_id, claim.attempt
            )
            shutil.rmtree(work, ignore_errors=True)
            return
        log.info(
            "job %s: %d points in %d tiles, planned in %.1f s; tiles queued",
            claim.job_id,
            plan.points,
            len(plan.tiles),
            seconds,
        )
        for box in plan.tiles:
            self._enqueue(claim.job_id, "tile", box.index)

    def _enqueue(self, job_id: str, kind: str, tile: int = 0) -> None:
        try:
            self.context.queue.enqueue_part(job_id, kind, tile)
        except QueueUnavailable:  # the reaper enqueues parts queued without a queue entry
            log.warning("job %s: %s %d not enqueued; the reaper will", job_id, kind, tile)

    # -- tiles and the merge: any worker --------------------------------------------------

    def tile(self, job_id: str, tile: int) -> None:
        """The task of tile ``tile`` of ``job_id``."""
        self._part(job_id, "tile", tile)

    def merge(self, job_id: str) -> None:
        """The task of the merge of ``job_id``."""
        self._part(job_id, "merge", 0)

    def _part(self, job_id: str, kind: str, tile: int) -> None:
        with self.sessions() as session:
            part = parts.claim_part(session, job_id, kind, tile, self.context.worker)
        if part is None:
            log.info("job %s: %s %d not queued any more, skipped", job_id, kind, tile)
            self._settle(job_id)
            return
        self.context.current = part
        self.context.fit_threads()
        log.info(
            "job %s: %s attempt %d started by %s",
            job_id,
            part.name,
            part.attempt,
            self.context.worker,
        )
        token = RowCancelToken(self.sessions, part, self.context.stopping)
        upload = self.storage.upload_path(job_id, f".{part.format}")
        work = self.storage.tiles_dir(job_id, part.job_attempt)
        try:
            config = PipelineConfig.model_validate(part.config)
            if kind == "tile":
                self._tile(part, config, work, token)
            else:
                self._merge(part, config, work, upload, token)
        except Cancelled:
            self._stopped(part, token)
        except (JointsegError, ValidationError) as exc:
            message = _public(exc, upload, part.filename, work)
            self._failed(part, message)
        except Exception as exc:
            if token.is_set():  # e.g. the folder went away under a cancelled tile
                log.info("job %s: %s stopped: %s", job_id, part.name, exc)
                self._stopped(part, token)
            else:
                log.exception("job %s: %s: internal error", job_id, part.name)
                error = f"internal error: {type(exc).__name__}: {exc}"
                self._failed(part, one_line(without_server_paths(error)))
        finally:
            self.context.current = None

    def _tile(
        self, part: parts.PartClaim, config: PipelineConfig, work: Path, token: RowCancelToken
    ) -> None:
        # deferred: running a tile loads torch and open3d
        from jointseg.pipeline import tiled

        started = time.perf_counter()
        predictor, _ = self.context.predictor(config)
        ran = tiled.run_tile(
            work,
            part.tile,
            config,
            predictor=predictor,
            progress=PartProgress(self.sessions, part, TILE_WEIGHTS),
            cancel=token,
            skip_done=True,
        )
        if not ran:
            log.info(
                "job %s: %s already has its result (an earlier attempt)", part.job_id, part.name
            )
        seconds = time.perf_counter() - started
        with self.sessions() as session:
            ours, merge_due = parts.finish_tile(session, part, seconds)
        if not ours:
            log.warning("job %s: %s attempt no longer ours", part.job_id, part.name)
            return
        log.info("job %s: %s done in %.1f s", part.job_id, part.name, seconds)
        if merge_due:
            log.info("job %s: every tile done; merge queued", part.job_id)
            self._enqueue(part.job_id, "merge")
        self._settle(part.job_id)

    def _merge(
        self,
        part: parts.PartClaim,
        config: PipelineConfig,
        work: Path,
        upload: Path,
        token: RowCancelToken,
    ) -> None:
        # deferred: the merge loads the fusion and the streamed writers
        from jointseg.pipeline import tiled

        started = time.perf_counter()
        done = tiled.finish(
            work,
            config,
            upload,
            self.storage.result_path(part.job_id, "ply"),
            max_points=self.settings.max_points,
            progress=PartProgress(self.sessions, part, MERGE_WEIGHTS),
            cancel=token,
        )
        with self.sessions() as session:
            timings = parts.timings(session, part.job_id)  # total: since the job started
        timings.update(done.timings)
        timings["merge"] = time.perf_counter() - started
        body: dict[str, Any] = {"input": part.filename, "output": "result.ply"}
        body.update(done.report(config, timings))
        self.storage.write_bytes(
            self.storage.report_path(part.job_id), json.dumps(body, indent=2).encode()
        )
        rounded = {k: round(float(v), 4) for k, v in timings.items()}
        with self.sessions() as session:
            finished = parts.finish_merge(
                session,
                part,
                seconds=time.perf_counter() - started,
                points=done.plan.points,
                timings=rounded,
            )
        if not finished:
            log.warning("job %s: merge attempt no longer ours", part.job_id)
            return
        job_finished("scan", "succeeded", rounded)
        log.info(
            "job %s succeeded: %d points in %d tiles, %.1f s",
            part.job_id,
            done.plan.points,
            len(done.plan.tiles),
            rounded.get("total", 0.0),
        )
        self._settle(part.job_id)

    # -- how a part ends otherwise ----------------------------------------------------------

    def _stopped(self, part: parts.PartClaim, token: RowCancelToken) -> None:
        """A cancel, the job's end, or this worker's shutdown: skipped, or back to the queue."""
        if self.context.stopping.is_set() and not token.requested:
            with self.sessions() as session:
                released = parts.release_part(session, part)
            if released:
                log.info("job %s: worker stopping, %s re-queued", part.job_id, part.name)
                self._enqueue(part.job_id, part.kind, part.tile)
                return
        with self.sessions() as session:
            parts.stop_part(session, part)
        log.info("job %s: %s stopped", part.job_id, part.name)
        self._settle(part.job_id)

    def _failed(self, part: parts.PartClaim, message: str) -> None:
        error = f"{part.name} failed: {message}"
        with self.sessions() as session:
            failed = parts.fail_part(session, part, error)
        if failed:
            log.info("job %s failed: %s", part.job_id, error)
            job_finished("scan", "failed", None, part.kind)
            self._settle(part.job_id)
        else:
            log.warning("job %s: %s attempt no longer ours", part.job_id, part.name)

    def _settle(self, job_id: str) -> None:
        """Finish a cancel nobody is left to finish; remove the folder of a job that ended."""
        with self.sessions() as session:
            if parts.settle_cancel(session, job_id):
                log.info("job %s cancelled", job_id)
            idle = parts.idle_and_final(session, job_id)
        if idle:
            self.storage.remove_tiles(job_id)


def _clear(folder: Path) -> None:
    """Remove ``folder`` (a job's tile folders from earlier attempts)."""
    if folder.exists():
        shutil.rmtree(folder, ignore_errors=True)


def _public(exc: BaseException, upload: Path, filename: str, work: Path) -> str:
    """The failure as the client sees it: no server paths (the tile folder is named as such)."""
    if isinstance(exc, ValidationError):
        return one_line(str(ConfigError(f"config: {exc}")))
    return public_message(exc, upload, filename, {str(work): "<tile folder>"})
