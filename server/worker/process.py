"""A worker process: Huey's consumer (one thread) running jobs through :class:`JobRunner`,
and the tiles and merges of tiled jobs through its :class:`server.worker.fanout.FanOut`.

This module only wires the process together: settings, database, queue, the runner as the
queue's task handlers, signals, and the heartbeat process (:mod:`server.worker.pulse`) that
stamps the worker and its claim as alive. The main thread runs the reaper and waits for
SIGTERM / SIGINT, upon which the running job stops at its next cancel check and goes
back to the queue for another worker.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from collections.abc import Callable
from types import FrameType

from server.lifeline import STOP_GRACE_S, die_with_parent
from server.logs import configure_logging
from server.queue import MERGE_TILES, RUN_TILE, JobQueue, set_handler
from server.settings import Settings
from server.state import lifecycle
from server.state.db import init_db, make_engine, make_sessions
from server.state.reaper import reap_and_requeue
from server.storage import Storage
from server.worker.context import WorkerContext, machine_cores
from server.worker.pulse import Pulse
from server.worker.runner import JobRunner

log = logging.getLogger(__name__)


def _torch_threads(settings: Settings) -> int:
    if settings.torch_threads is not None:
        return settings.torch_threads
    return max(1, machine_cores() // max(1, settings.workers))


def worker_main(settings: Settings, *, parent_pid: int | None = None) -> None:
    """Run one worker process until SIGTERM / SIGINT (or until ``parent_pid`` exits).

    Parameters
    ----------
    settings : Settings
    parent_pid : int, optional
        The ``jointseg serve`` process that spawned this worker; when it disappears (even by
        SIGKILL) the worker gets SIGTERM (it puts its job back in the queue and exits) and is
        killed if still alive after the stop grace period (:mod:`server.lifeline`).
    """
    if parent_pid is not None:  # first, so an orphan never even loads torch
        die_with_parent(parent_pid, grace_s=STOP_GRACE_S)
    # deferred: torch is heavy, and the `jointseg serve` API process imports this module only
    # to name the workers' spawn target
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
    context = WorkerContext(settings, sessions, storage, queue, stopping)
    runner = JobRunner(context)
    set_handler(runner)
    set_handler(runner.fanout.tile, RUN_TILE)
    set_handler(runner.fanout.merge, MERGE_TILES)
    consumer = queue.huey.create_consumer(
        workers=1,
        worker_type="thread",
        periodic=False,
        initial_delay=0.05,
        max_delay=settings.queue_poll_s,
        check_worker_health=True,
    )

    def stop(signum: int, _frame: FrameType | None) -> None:
        log.info("worker %s: %s received, stopping", context.worker, signal.Signals(signum).name)
        stopping.set()

    context.pulse = Pulse(settings, context.worker)
    consumer.start()
    signal.signal(signal.SIGTERM, stop)  # replaces the consumer's handlers
    signal.signal(signal.SIGINT, stop)
    log.info(
        "worker %s ready (%s queue, %d torch threads)",
        context.worker,
        queue.kind,
        torch.get_num_threads(),
    )
    _main_loop(context, parent_pid)
    consumer.stop(graceful=True)
    context.pulse.stop()
    with sessions() as session:
        lifecycle.forget_worker(session, context.worker)
    queue.close()
    engine.dispose()
    log.info("worker %s stopped", context.worker)


def _keep_pulse(context: WorkerContext) -> None:
    """Start the heartbeat process again if it died (the worker would look dead otherwise)."""
    if context.pulse is not None and not context.pulse.alive():
        log.warning("worker %s: heartbeat process died; starting it again", context.worker)
        context.pulse = Pulse(context.settings, context.worker)
        context.pulse.claim(context.current)


def _main_loop(context: WorkerContext, parent_pid: int | None) -> None:
    """The reaper every ``heartbeat_interval_s`` (the heartbeats are the pulse's), and the
    pulse started again should it die, until asked to stop."""
    settings = context.settings
    tasks: list[Callable[[], object]] = [
        lambda: _keep_pulse(context),
        lambda: reap_and_requeue(context.sessions, context.queue, settings),
    ]
    while not context.stopping.wait(settings.heartbeat_interval_s):
        if parent_pid is not None and os.getppid() != parent_pid:
            log.warning("worker %s: parent %d is gone, stopping", context.worker, parent_pid)
            context.stopping.set()
            break
        for task in tasks:
            try:
                task()
            except Exception:  # noqa: BLE001 - keep beating through a database hiccup
                log.warning("worker %s: periodic task failed", context.worker, exc_info=True)
