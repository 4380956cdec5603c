"""`jointseg serve`: the API in this process, workers and extra processes spawned beside it.

Children are started with the ``spawn`` method (a fresh interpreter, never a fork of a process
that has initialised torch). A worker that dies (even by SIGKILL) is restarted; its job is
recovered by the reaper. Ctrl-C or SIGTERM stops uvicorn, then every child: each gets SIGTERM,
finishes or re-queues its job, and is killed only if it has not exited after a grace period.
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
from server.logs import configure_logging
from server.serve_parts import ExtraProcess
from server.settings import Settings
from server.state.db import init_db, make_engine
from server.worker.process import worker_main

log = logging.getLogger(__name__)

#: Seconds a child gets to exit after SIGTERM before it is killed.
STOP_GRACE_S = 20.0
#: Shortest time between two restarts of the same worker slot.
RESTART_BACKOFF_S = 1.0


def _run_extra(target: ExtraProcess, settings: Settings) -> None:
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
                target=_run_extra, args=(target, self.settings), name=f"jointseg-{target.__name__}"
            )
            process.start()
            self.extra.append(process)
            log.info("started %s (pid %s)", process.name, process.pid)
        self._watch.start()

    def _watch_workers(self) -> None:
        restarted = [0.0] * len(self.workers)
        while not self.stopping.wait(0.5):
            for slot, process in enumerate(self.workers):
                if process.is_alive() or self.stopping.is_set():
                    continue
                if time.monotonic() - restarted[slot] < RESTART_BACKOFF_S:
                    continue
                log.warning(
                    "worker %d (pid %s) exited with %s; restarting it",
                    slot + 1,
                    process.pid,
                    process.exitcode,
                )
                restarted[slot] = time.monotonic()
                self.workers[slot] = self._spawn_worker(slot)

    def stop(self) -> None:
        self.stopping.set()
        if self._watch.is_alive():
            self._watch.join()
        children = [p for p in self.workers + self.extra if p.is_alive()]
        for process in children:
            process.terminate()  # SIGTERM: workers re-queue a running job and exit
        deadline = time.monotonic() + STOP_GRACE_S
        for process in children:
            process.join(max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                log.warning("%s did not stop in %.0f s; killing it", process.name, STOP_GRACE_S)
                process.kill()
                process.join()
        log.info("all %d child processes stopped", len(children))


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
