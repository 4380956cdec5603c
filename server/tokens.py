"""How a running job talks to its row: progress written out, cancel requests read back.

The pipeline only knows ``progress(stage, fraction)`` callbacks and ``is_set()`` tokens; these
implement them on the job row, throttled so a stage reporting thousands of times costs a few
database round trips.
"""

from __future__ import annotations

import logging
import threading
import time

from server import lifecycle
from server.db import SessionFactory

log = logging.getLogger(__name__)

#: Share of the overall progress each stage stands for (network and geometry run together).
STAGE_WEIGHTS = {"read": 0.1, "network": 0.5, "geometry": 0.25, "fusion": 0.05, "write": 0.1}
#: Seconds between two writes of progress, and between two reads of the cancel flag.
PROGRESS_EVERY_S = 0.5
CANCEL_EVERY_S = 0.5


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
