"""The worker's heartbeat, in a small process of its own, so nothing the worker runs can starve
it.

Why a process: the forward pass, open3d and other native code may hold the GIL for seconds on
a big scan, and a heartbeat thread would then miss its beats, so the lease had to be long (a
minute) and a dead worker's tile waited that long. The pulse process holds no GIL of the
worker's: it stamps the worker, and the job or tile the worker says it is on, every
``heartbeat_interval_s`` through its own database connection. It dies with its worker, at once
on Linux (``PR_SET_PDEATHSIG``, :mod:`server.lifeline`), so a killed worker's lease expires
``heartbeat_timeout_s`` later (10 s by default) and its work runs again.

The worker tells it which claim it is on through a pipe (:meth:`Pulse.claim`); a claim is two
small dataclasses, pickled.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from multiprocessing.connection import Connection
from typing import Any

from server.lifeline import die_with_parent
from server.settings import Settings
from server.state import lifecycle, parts

log = logging.getLogger(__name__)

#: Seconds the worker waits for its pulse to stop before killing it.
STOP_S = 5.0
_STOP = "stop"


class Pulse:
    """The heartbeat process of one worker (started at once; :meth:`stop` ends it)."""

    def __init__(self, settings: Settings, worker: str) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._lock = threading.Lock()
        self.process = ctx.Process(
            target=pulse_main,
            args=(settings, worker, child, os.getpid()),
            name=f"jointseg-pulse-{worker}",
        )
        self.process.start()
        child.close()

    def claim(self, current: Any) -> None:
        """The claim (job or part) the worker is on now, None when idle."""
        with self._lock:
            try:
                self._conn.send(current)
            except (BrokenPipeError, OSError):
                log.warning("the heartbeat process is gone (pid %s)", self.process.pid)

    def alive(self) -> bool:
        return self.process.is_alive()

    def stop(self) -> None:
        """End the pulse (the worker forgets itself in the database after this)."""
        self.claim(_STOP)
        self.process.join(STOP_S)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(STOP_S)


def pulse_main(settings: Settings, worker: str, conn: Connection, parent_pid: int) -> None:
    """Stamp ``worker`` and its claim alive every ``heartbeat_interval_s`` until told to stop
    or until the worker (``parent_pid``) is gone."""
    die_with_parent(parent_pid, sig=signal.SIGKILL, grace_s=0.0)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C stops the worker, which stops this
    from server.logs import configure_logging
    from server.state.db import make_engine, make_sessions

    configure_logging(settings)
    engine = make_engine(settings)
    sessions = make_sessions(engine)
    current: Any = None
    try:
        while True:
            while conn.poll(0):
                message = conn.recv()
                if message == _STOP:
                    return
                current = message
            beat(sessions, current, worker)
            if conn.poll(settings.heartbeat_interval_s):
                continue  # a new claim: stamp it now
    except (EOFError, OSError):
        return  # the worker closed its end: it is gone
    finally:
        engine.dispose()


def beat(sessions: Any, current: Any, worker: str) -> None:
    """One heartbeat: the worker, and the part or job it is on."""
    try:
        with sessions() as session:
            if isinstance(current, parts.PartClaim):
                parts.heartbeat(session, current, worker)
            else:
                lifecycle.heartbeat(session, current, worker)
    except Exception:  # noqa: BLE001 - the next beat may succeed
        log.warning("worker %s: heartbeat failed", worker, exc_info=True)
