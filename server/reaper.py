"""Recovering jobs of lost workers: stale running jobs and queued jobs missing from the queue.

Both the API process and every worker sweep periodically, so jobs are recovered even when
every worker is gone (see :func:`server.lifecycle.reap_stale`).
"""

from __future__ import annotations

import logging
import threading

from server import lifecycle
from server.db import SessionFactory
from server.queue import JobQueue
from server.settings import Settings

log = logging.getLogger(__name__)


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
