"""Recovering jobs of lost workers: stale running jobs and queued jobs missing from the queue,
and the same for the tiles and merges of tiled jobs.

Both the API process and every worker sweep periodically, so jobs are recovered even when
every worker is gone (see :func:`server.state.lifecycle.reap_stale` and
:func:`server.state.part_reaper.reap_parts`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import TypeVar

from server.queue import JobQueue
from server.settings import Settings
from server.state import lifecycle
from server.state.db import SessionFactory
from server.state.part_reaper import PartKey, queued_parts_before, reap_parts
from server.storage import Storage

log = logging.getLogger(__name__)
T = TypeVar("T", str, PartKey)


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
    requeued += _orphans(waiting - set(requeued), queue.pending_ids, _job_name)
    for job_id in requeued:
        queue.enqueue(job_id)
    reap_tiles(sessions, queue, settings)
    return requeued


def recover_dead_worker(
    sessions: SessionFactory, queue: JobQueue, settings: Settings, worker: str
) -> list[str]:
    """Re-queue at once the job (or tile, or merge) of a worker whose process has exited, and
    remove its worker row; returns the ids of the jobs re-queued.

    Why: ``jointseg serve`` sees its worker die within half a second, while the heartbeat
    timeout is a minute; waiting for it left the job stuck and the dead worker in /healthz.
    The attempt counts, as when the reaper finds the job: the process may have died of it.
    """
    with sessions() as session:
        requeued = lifecycle.reap_stale(
            session,
            timeout_s=settings.heartbeat_timeout_s,
            max_attempts=settings.max_attempts,
            dead=worker,
        )
    for job_id in requeued:
        queue.enqueue(job_id)
    reap_tiles(sessions, queue, settings, dead=worker)
    return requeued


def reap_tiles(
    sessions: SessionFactory, queue: JobQueue, settings: Settings, *, dead: str | None = None
) -> None:
    """The sweep over tiled jobs' parts: re-queue stale ones (or those of the ``dead`` worker),
    queue lost merges, enqueue queued parts missing from the queue, finish cancels, remove the
    tile folders of jobs that ended."""
    with sessions() as session:
        sweep = reap_parts(
            session,
            timeout_s=settings.heartbeat_timeout_s,
            max_attempts=settings.max_attempts,
            dead=dead,
        )
        waiting = set(queued_parts_before(session, timeout_s=settings.heartbeat_timeout_s))
    sweep.enqueue += _orphans(waiting - set(sweep.enqueue), queue.pending_parts, _part_name)
    for job_id, kind, tile in sweep.enqueue:
        queue.enqueue_part(job_id, kind, tile)
    if sweep.idle:
        storage = Storage(settings.data_dir)
        for job_id in sweep.idle:
            storage.remove_tiles(job_id)


def _orphans(waiting: set[T], pending: Callable[[], set[T]], name: Callable[[T], str]) -> list[T]:
    """Of the rows queued for longer than the heartbeat timeout, those without a queue entry
    (their enqueue failed, or the process re-queueing them died between commit and enqueue);
    the queue is asked only when some row waits. Enqueueing one twice is harmless."""
    if not waiting:
        return []
    orphans = sorted(waiting - pending())
    for key in orphans:
        log.warning("%s was queued without a queue entry; enqueueing it", name(key))
    return orphans


def _job_name(job_id: str) -> str:
    return f"job {job_id}"


def _part_name(key: PartKey) -> str:
    job_id, kind, tile = key
    return f"job {job_id}: {kind} {tile}"


class ReaperThread:
    """:func:`reap_and_requeue` every ``heartbeat_interval_s`` in a daemon thread (the API's)."""

    def __init__(self, sessions: SessionFactory, queue: JobQueue, settings: Settings) -> None:
        self.sessions = sessions
        self.queue = queue
        self.settings = settings
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="jointseg-reaper", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop sweeping and wait up to ``timeout`` seconds for a sweep in progress."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=timeout)

    def _loop(self) -> None:
        while not self._stop.wait(self.settings.heartbeat_interval_s):
            try:
                reap_and_requeue(self.sessions, self.queue, self.settings)
            except Exception:  # noqa: BLE001 - retried at the next interval
                log.warning("reaper failed", exc_info=True)
