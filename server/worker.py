"""A worker process: Huey's consumer (one thread) running jobs through ``jointseg.pipeline``.

The network is loaded once per process and configuration and kept. While a job runs, the job
row receives its stage and progress (at most every half second) and a heartbeat; the row's
cancel flag is read back through :class:`RowCancelToken`. The main thread stamps the worker as
alive, runs the reaper and waits for SIGTERM / SIGINT, upon which the running job stops at its
next cancel check and goes back to the queue for another worker.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from types import FrameType
from typing import Any

from pydantic import ValidationError

from jointseg.exceptions import Cancelled, ConfigError, JointsegError
from jointseg.io import read_scan, write_scan
from jointseg.network import Predictor
from jointseg.pipeline import PipelineConfig, annotate, load_predictor, report_body, run
from server import lifecycle
from server.db import SessionFactory, init_db, make_engine, make_sessions
from server.queue import JobQueue, set_handler
from server.settings import Settings
from server.storage import Storage

log = logging.getLogger(__name__)

#: Share of the overall progress each stage stands for (network and geometry run together).
STAGE_WEIGHTS = {"read": 0.1, "network": 0.5, "geometry": 0.25, "fusion": 0.05, "write": 0.1}
#: Seconds between two writes of progress, and between two reads of the cancel flag.
PROGRESS_EVERY_S = 0.5
CANCEL_EVERY_S = 0.5
#: Networks kept loaded per process (one per configuration).
MAX_PREDICTORS = 2


class RowCancelToken:
    """``is_set()`` true when the job row asks to cancel or this worker is stopping.

    The row is read at most every :data:`CANCEL_EVERY_S` seconds however often stages ask.
    """

    def __init__(
        self, sessions: SessionFactory, claim: lifecycle.Claim, stopping: threading.Event
    ) -> None:
        self.sessions = sessions
        self.claim = claim
        self.stopping = stopping
        self.requested = False
        self._checked = 0.0
        self._lock = threading.Lock()

    def is_set(self) -> bool:
        if self.stopping.is_set() or self.requested:
            return True
        with self._lock:
            now = time.monotonic()
            if now - self._checked >= CANCEL_EVERY_S:
                self._checked = now
                try:
                    with self.sessions() as session:
                        self.requested = lifecycle.cancel_requested(session, self.claim)
                except Exception:  # noqa: BLE001 - a database hiccup must not kill the job
                    log.warning("job %s: cannot read the cancel flag", self.claim.job_id)
        return self.requested


class RowProgress:
    """A ``progress(stage, fraction)`` callback that writes overall progress to the job row."""

    def __init__(self, sessions: SessionFactory, claim: lifecycle.Claim) -> None:
        self.sessions = sessions
        self.claim = claim
        self.fractions: dict[str, float] = {}
        self.stage = "queued"
        self.overall = 0.0
        self._written = 0.0

    def __call__(self, stage: str, fraction: float) -> None:
        self.fractions[stage] = fraction
        self.stage = stage
        total = sum(w * self.fractions.get(s, 0.0) for s, w in STAGE_WEIGHTS.items())
        self.overall = max(self.overall, min(1.0, total))
        now = time.monotonic()
        if now - self._written >= PROGRESS_EVERY_S:
            self.flush()
            self._written = now

    def flush(self) -> None:
        """Write the current stage and progress now."""
        try:
            with self.sessions() as session:
                lifecycle.record_progress(session, self.claim, self.stage, self.overall)
        except Exception:  # noqa: BLE001 - progress is best effort
            log.warning("job %s: cannot record progress", self.claim.job_id)


class JobRunner:
    """Runs one job id at a time in this process, keeping loaded networks between jobs."""

    def __init__(
        self,
        settings: Settings,
        sessions: SessionFactory,
        storage: Storage,
        queue: JobQueue,
        stopping: threading.Event,
    ) -> None:
        self.settings = settings
        self.sessions = sessions
        self.storage = storage
        self.queue = queue
        self.stopping = stopping
        self.worker = lifecycle.worker_id()
        self.current: lifecycle.Claim | None = None
        self.predictors: OrderedDict[str, Predictor] = OrderedDict()

    def predictor(self, config: PipelineConfig) -> tuple[Predictor, float]:
        """The loaded network for ``config.network`` and the seconds loading took (0 if kept)."""
        key = json.dumps(config.network.model_dump(mode="json"), sort_keys=True)
        if key in self.predictors:
            self.predictors.move_to_end(key)
            return self.predictors[key], 0.0
        started = time.perf_counter()
        predictor = load_predictor(config.network)
        self.predictors[key] = predictor
        while len(self.predictors) > MAX_PREDICTORS:
            self.predictors.popitem(last=False)
        return predictor, time.perf_counter() - started

    def __call__(self, job_id: str) -> None:
        """Run job ``job_id`` unless it was cancelled or claimed meanwhile."""
        with self.sessions() as session:
            claim = lifecycle.claim_job(session, job_id, self.worker)
        if claim is None:
            log.info("job %s: not queued any more, skipped", job_id)
            return
        self.current = claim
        log.info("job %s: attempt %d started by %s", job_id, claim.attempt, self.worker)
        try:
            self._run(claim)
        finally:
            self.current = None

    def _run(self, claim: lifecycle.Claim) -> None:
        token = RowCancelToken(self.sessions, claim, self.stopping)
        progress = RowProgress(self.sessions, claim)
        upload = self.storage.upload_path(claim.job_id, f".{claim.format}")
        try:
            points, timings = self._pipeline(claim, upload, progress, token)
        except Cancelled:
            self._stopped(claim, token)
            return
        except (JointsegError, ValidationError) as exc:
            message = _public_message(exc, upload, claim.filename)
            log.info("job %s failed: %s", claim.job_id, message)
            self._finish(claim, "failed", error=message)
            return
        except Exception as exc:
            log.exception("job %s: internal error", claim.job_id)
            self._finish(claim, "failed", error=f"internal error: {type(exc).__name__}: {exc}")
            return
        self._finish(claim, "succeeded", points=points, timings=timings)
        log.info("job %s succeeded: %d points in %.1f s", claim.job_id, points, timings["total"])

    def _pipeline(
        self,
        claim: lifecycle.Claim,
        upload: Path,
        progress: RowProgress,
        token: RowCancelToken,
    ) -> tuple[int, dict[str, float]]:
        config = PipelineConfig.model_validate(claim.config)
        progress("read", 0.0)
        progress.flush()
        predictor, load_s = self.predictor(config)
        started = time.perf_counter()
        scan = read_scan(upload, max_points=self.settings.max_points, progress=progress)
        read_s = time.perf_counter() - started
        result = run(scan, config, progress, token, predictor=predictor)
        if token.is_set():
            raise Cancelled("cancelled by request")
        started = time.perf_counter()
        write_scan(annotate(scan, result), self.storage.result_path(claim.job_id, "ply"))
        write_s = time.perf_counter() - started
        extra = {"load_network": load_s, "read": read_s, "write": write_s}
        body: dict[str, Any] = {"input": claim.filename, "output": "result.ply"}
        body.update(report_body(scan, result, extra_timings=extra))
        self.storage.write_bytes(
            self.storage.report_path(claim.job_id), json.dumps(body, indent=2).encode()
        )
        return len(scan), {k: round(float(v), 4) for k, v in body["timings_s"].items()}

    def _stopped(self, claim: lifecycle.Claim, token: RowCancelToken) -> None:
        """A cancel request, or this worker's shutdown: cancelled, or back to the queue."""
        if self.stopping.is_set() and not token.requested:
            with self.sessions() as session:
                released = lifecycle.release_job(session, claim)
            if released:
                log.info("job %s: worker stopping, job re-queued", claim.job_id)
                self.queue.enqueue(claim.job_id)
                return
        self._finish(claim, "cancelled", error="cancelled by request")
        log.info("job %s cancelled", claim.job_id)

    def _finish(self, claim: lifecycle.Claim, status: str, **values: Any) -> None:
        with self.sessions() as session:
            if not lifecycle.finish_job(session, claim, status, **values):
                log.warning("job %s: attempt %d no longer ours", claim.job_id, claim.attempt)


def _public_message(exc: BaseException, upload: Path, filename: str) -> str:
    """The error's message with server paths replaced by the user's file name."""
    if isinstance(exc, ValidationError):
        return str(ConfigError(f"config: {exc}"))
    return str(exc).replace(str(upload), filename)


def reap_and_requeue(sessions: SessionFactory, queue: JobQueue, settings: Settings) -> list[str]:
    """Run the reaper once and enqueue the jobs it put back (shared by API and workers).

    It also enqueues orphans: jobs queued for longer than the heartbeat timeout whose id is
    not in the queue. Enqueueing a job twice is harmless (the second claim finds it taken).
    """
    with sessions() as session:
        requeued = lifecycle.reap_stale(
            session, timeout_s=settings.heartbeat_timeout_s, max_attempts=settings.max_attempts
        )
        waiting = set(lifecycle.queued_before(session, timeout_s=settings.heartbeat_timeout_s))
    waiting -= set(requeued)
    if waiting:
        orphans = sorted(waiting - queue.pending_ids())
        for job_id in orphans:
            log.warning("job %s was queued without a queue entry; enqueueing it", job_id)
        requeued += orphans
    for job_id in requeued:
        queue.enqueue(job_id)
    return requeued


def configure_logging(settings: Settings) -> None:
    """Log lines with process id, so several workers can share one terminal."""
    logging.basicConfig(
        level=settings.log_level.upper(),
        format="%(asctime)s %(levelname)s [%(process)d] %(name)s: %(message)s",
        force=True,
    )


def _torch_threads(settings: Settings) -> int:
    if settings.torch_threads is not None:
        return settings.torch_threads
    return max(1, (os.cpu_count() or 1) // max(1, settings.workers))


def worker_main(settings: Settings, *, parent_pid: int | None = None) -> None:
    """Run one worker process until SIGTERM / SIGINT (or until ``parent_pid`` exits).

    Parameters
    ----------
    settings : Settings
    parent_pid : int, optional
        The ``jointseg serve`` process that spawned this worker; when it disappears (even by
        SIGKILL) the worker stops too instead of running on as an orphan.
    """
    import torch

    configure_logging(settings)
    if settings.worker_nice:
        os.nice(settings.worker_nice)
    torch.set_num_threads(_torch_threads(settings))
    engine = make_engine(settings)
    init_db(engine)
    sessions = make_sessions(engine)
    storage = Storage(settings.data_dir)
    queue = JobQueue(settings)
    stopping = threading.Event()
    runner = JobRunner(settings, sessions, storage, queue, stopping)
    set_handler(runner)
    consumer = queue.huey.create_consumer(
        workers=1,
        worker_type="thread",
        periodic=False,
        initial_delay=0.05,
        max_delay=settings.queue_poll_s,
        check_worker_health=True,
    )

    def stop(signum: int, _frame: FrameType | None) -> None:
        log.info("worker %s: %s received, stopping", runner.worker, signal.Signals(signum).name)
        stopping.set()

    _beat(sessions, runner)
    consumer.start()
    signal.signal(signal.SIGTERM, stop)  # replaces the consumer's handlers
    signal.signal(signal.SIGINT, stop)
    log.info(
        "worker %s ready (%s queue, %d torch threads)",
        runner.worker,
        queue.kind,
        torch.get_num_threads(),
    )
    _main_loop(settings, sessions, queue, runner, stopping, parent_pid)
    consumer.stop(graceful=True)
    with sessions() as session:
        lifecycle.forget_worker(session, runner.worker)
    queue.close()
    engine.dispose()
    log.info("worker %s stopped", runner.worker)


def _beat(sessions: SessionFactory, runner: JobRunner) -> None:
    try:
        with sessions() as session:
            lifecycle.heartbeat(session, runner.current, runner.worker)
    except Exception:  # noqa: BLE001 - the next beat may succeed
        log.warning("worker %s: heartbeat failed", runner.worker, exc_info=True)


def _main_loop(
    settings: Settings,
    sessions: SessionFactory,
    queue: JobQueue,
    runner: JobRunner,
    stopping: threading.Event,
    parent_pid: int | None,
) -> None:
    """Heartbeats and the reaper, every ``heartbeat_interval_s``, until asked to stop."""
    tasks: list[Callable[[], object]] = [
        lambda: _beat(sessions, runner),
        lambda: reap_and_requeue(sessions, queue, settings),
    ]
    while not stopping.wait(settings.heartbeat_interval_s):
        if parent_pid is not None and os.getppid() != parent_pid:
            log.warning("worker %s: parent %d is gone, stopping", runner.worker, parent_pid)
            stopping.set()
            break
        for task in tasks:
            try:
                task()
            except Exception:  # noqa: BLE001 - keep beating through a database hiccup
                log.warning("worker %s: periodic task failed", runner.worker, exc_info=True)
