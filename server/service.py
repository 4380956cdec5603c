"""`jointseg serve`: the API in this process, workers and extra processes spawned beside it.

Children are started with the ``spawn`` method (a fresh interpreter, never a fork of a process
that has initialised torch). A worker that dies (even by SIGKILL) is seen within half a second:
its job goes back to the queue at once (:func:`server.state.reaper.recover_dead_worker`), its
row leaves /healthz, and it is restarted. Ctrl-C or SIGTERM stops uvicorn, then every child:
each gets SIGTERM, finishes or re-queues its job, and is killed only if it has not exited after
a grace period. When ``serve`` itself dies, even by SIGKILL, its children follow
(:mod:`server.lifeline`).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Sequence
from multiprocessing.process import BaseProcess
from types import FrameType

import uvicorn
from fastapi import APIRouter

from server.api.app import create_app
from server.lifeline import STOP_GRACE_S, die_with_parent
from server.logs import configure_logging
from server.queue import JobQueue
from server.serve_parts import ExtraProcess
from server.settings import Settings
from server.state import lifecycle
from server.state.db import init_db, make_engine, make_sessions
from server.state.reaper import recover_dead_worker
from server.worker.process import worker_main

log = logging.getLogger(__name__)

#: Shortest time between two restarts of the same worker slot.
RESTART_BACKOFF_S = 1.0
#: Seconds between two looks at the workers.
WATCH_INTERVAL_S = 0.5
#: Seconds an extra process (the viewer) gets to exit on SIGTERM once ``serve`` is gone.
EXTRA_GRACE_S = 5.0


def _run_extra(target: ExtraProcess, settings: Settings, parent_pid: int) -> None:
    die_with_parent(parent_pid, grace_s=EXTRA_GRACE_S)
    configure_logging(settings)
    target(settings)


class _Children:
    """The spawned processes, and a thread restarting workers that die."""

    def __init__(self, settings: Settings, extra: Sequence[ExtraProcess]) -> None:
        self.settings = settings
        self.ctx = multiprocessing.get_context("spawn")
        self.workers: list[BaseProcess] = []
        self.extra: list[BaseProcess] = []
        self.extra_targets = list(extra)
        self.stopping = threading.Event()
        self._watch = threading.Thread(target=self._watch_workers, name="jointseg-supervisor")
        self._recovered: set[int] = set()  # pids of dead workers whose jobs went back
        # the supervisor's own connections, to put a dead worker's job back at once
        self._engine = make_engine(settings)
        self._sessions = make_sessions(self._engine)
        self._queue = JobQueue(settings)

    def _spawn_worker(self, slot: int) -> BaseProcess:
        process = self.ctx.Process(
            target=worker_main,
            args=(self.settings,),
            kwargs={"parent_pid": os.getpid()},
            name=f"jointseg-worker-{slot + 1}",
        )
        process.start()
        log.info("started worker %d (pid %s)", slot + 1, process.pid)
        return process

    def start(self) -> None:
        self.workers = [self._spawn_worker(i) for i in range(self.settings.workers)]
        for target in self.extra_targets:
            process = self.ctx.Process(
                target=_run_extra,
                args=(target, self.settings, os.getpid()),
                name=f"jointseg-{target.__name__}",
            )
            process.start()
            self.extra.append(process)
            log.info("started %s (pid %s)", process.name, process.pid)
        self._watch.start()

    def _watch_workers(self) -> None:
        """Every WATCH_INTERVAL_S: recover the job of a worker that died, restart it.

        Workers restarted here are children of this thread, which lives as long as the
        service: their PR_SET_PDEATHSIG (see :mod:`server.lifeline`) fires only at the stop.
        """
        restarted = [0.0] * len(self.workers)
        while not self.stopping.wait(WATCH_INTERVAL_S):
            for slot, process in enumerate(self.workers):
                if process.is_alive() or self.stopping.is_set():
                    continue
                try:
                    self._recover(slot, process)
                except Exception:  # noqa: BLE001 - e.g. the database is down: retried
                    log.warning("worker %d: its job not re-queued yet", slot + 1, exc_info=True)
                if time.monotonic() - restarted[slot] < RESTART_BACKOFF_S:
                    continue
                log.warning("restarting worker %d", slot + 1)
                restarted[slot] = time.monotonic()
                try:
                    self.workers[slot] = self._spawn_worker(slot)
                except Exception:  # noqa: BLE001 - the supervisor must outlive a failed start
                    log.exception("worker %d could not be restarted; retrying", slot + 1)

    def _recover(self, slot: int, process: BaseProcess) -> None:
        """Put the job of a worker that exited back in the queue and drop its /healthz row
        (once per dead process; if it fails until the worker is restarted, the reaper recovers
        the job after the heartbeat timeout)."""
        if process.pid is None or process.pid in self._recovered:
            return
        log.warning("worker %d (pid %s) exited with %s", slot + 1, process.pid, process.exitcode)
        worker = lifecycle.worker_id(process.pid)
        # logs each job, tile or merge it puts back ("job …: worker … died; now queued")
        recover_dead_worker(self._sessions, self._queue, self.settings, worker)
        self._recovered.add(process.pid)

    def stop(self) -> None:
        self.stopping.set()
        if self._watch.is_alive():
            self._watch.join()
        started = self.workers + self.extra
        children = [p for p in started if p.is_alive()]
        for process in children:
            process.terminate()  # SIGTERM: workers re-queue a running job and exit
        deadline = time.monotonic() + STOP_GRACE_S
        for process in children:
            process.join(max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                log.warning("%s did not stop in %.0f s; killing it", process.name, STOP_GRACE_S)
                process.kill()
                process.join()
        self._queue.close()
        self._engine.dispose()
        gone = len(started) - len(children)  # a Ctrl-C reaches the children first
        log.info(
            "all %d child processes stopped (%d were still running, %d had exited already)",
            len(started), len(children), gone,
        )  # fmt: skip


def run_service(
    settings: Settings,
    *,
    extra_routers: Sequence[APIRouter] = (),
    extra_processes: Sequence[ExtraProcess] = (),
) -> None:
    """Run the API, ``settings.workers`` workers and every extra process until Ctrl-C/SIGTERM.

    Parameters
    ----------
    settings : Settings
    extra_routers : sequence of APIRouter
        Added to the API app (e.g. the job page, from :func:`server.serve_parts.load_serve_parts`);
        they can depend on :func:`server.api.auth.require_api_key`.
    extra_processes : sequence of callables
        Each runs as ``target(settings)`` in its own spawned process (e.g. the viewer); it
        must be a module-level function and should exit on SIGTERM.
    """
    configure_logging(settings)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(settings)
    init_db(engine)  # once, before several processes race to create the tables
    engine.dispose()
    app = create_app(settings)
    for router in extra_routers:
        app.include_router(router)
    children = _Children(settings, extra_processes)
    children.start()
    server = uvicorn.Server(
        uvicorn.Config(
            app,
            host=settings.host,
            port=settings.port,
            log_level=settings.log_level.lower(),
            timeout_graceful_shutdown=10,
        )
    )
    received: list[int] = []

    def note(signum: int, _frame: FrameType | None) -> None:
        # uvicorn handles the signal while it runs and re-raises it when it has stopped: this
        # handler turns that into an orderly return instead of the default exit
        received.append(signum)

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, note)
    try:
        server.run()  # returns on SIGINT / SIGTERM
    finally:
        children.stop()
    if not server.started:
        raise SystemExit(1)
