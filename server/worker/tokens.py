"""How a running job talks to its row: progress written out, cancel requests read back.

The pipeline only knows ``progress(stage, fraction)`` callbacks and ``is_set()`` tokens; these
implement them on the job row (or, for a tile or the merge of a tiled job, on its part's row
and the job's), throttled so a stage reporting thousands of times costs a few database round
trips.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Mapping

from sqlalchemy.orm import Session

from server.state import lifecycle, parts
from server.state.db import SessionFactory

log = logging.getLogger(__name__)

#: Share of the overall progress each stage stands for (network and geometry run together).
STAGE_WEIGHTS = {
    "read": 0.08,
    "frame": 0.02,
    "network": 0.5,
    "geometry": 0.25,
    "fusion": 0.05,
    "write": 0.1,
}
#: The same for the parts of a tiled job: the plan (as a share of the whole job), one tile
#: (network and geometry run together), the merge.
PLAN_WEIGHTS = {"read": 0.7 * parts.PLAN_SHARE, "plan": 0.3 * parts.PLAN_SHARE}
TILE_WEIGHTS = {"network": 2 / 3, "geometry": 1 / 3}
MERGE_WEIGHTS = {"join": 0.3, "fusion": 0.3, "write": 0.4}
#: Seconds between two writes of progress, and between two reads of the cancel flag.
PROGRESS_EVERY_S = 0.5
CANCEL_EVERY_S = 0.5


class RowCancelToken:
    """``is_set()`` true when the job row asks to cancel or this worker is stopping (for a
    part of a tiled job: also when the job ended or the part is no longer this worker's).

    The row is read at most every :data:`CANCEL_EVERY_S` seconds however often stages ask.
    """

    def __init__(
        self,
        sessions: SessionFactory,
        claim: lifecycle.Claim | parts.PartClaim,
        stopping: threading.Event,
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
                        self.requested = _cancel_requested(session, self.claim)
                except Exception:  # noqa: BLE001 - a database hiccup must not kill the job
                    log.warning("job %s: cannot read the cancel flag", self.claim.job_id)
        return self.requested


def _cancel_requested(session: Session, claim: lifecycle.Claim | parts.PartClaim) -> bool:
    if isinstance(claim, parts.PartClaim):
        return parts.cancel_requested(session, claim)
    return lifecycle.cancel_requested(session, claim)


class RowProgress:
    """A ``progress(stage, fraction)`` callback that writes overall progress to the job row
    (``weights``: each stage's share of it; by default :data:`STAGE_WEIGHTS`)."""

    def __init__(
        self,
        sessions: SessionFactory,
        claim: lifecycle.Claim,
        weights: Mapping[str, float] = STAGE_WEIGHTS,
    ) -> None:
        self.sessions = sessions
        self.claim = claim
        self.weights = weights
        self.fractions: dict[str, float] = {}
        self.stage = "queued"
        self.overall = 0.0
        self._written = 0.0

    def __call__(self, stage: str, fraction: float) -> None:
        self.fractions[stage] = fraction
        self.stage = stage
        total = sum(w * self.fractions.get(s, 0.0) for s, w in self.weights.items())
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


class PartProgress:
    """A ``progress(stage, fraction)`` callback for a tile or the merge of a tiled job: writes
    the part's progress (``weights``: each stage's share of the part) and the job's, summed
    over its parts; the job's stage is ``tiles d/n`` during the tiles, the stage itself
    during the merge."""

    def __init__(
        self, sessions: SessionFactory, part: parts.PartClaim, weights: Mapping[str, float]
    ) -> None:
        self.sessions = sessions
        self.part = part
        self.weights = weights
        self.fractions: dict[str, float] = {}
        self.stage: str | None = None
        self.overall = 0.0
        self._written = 0.0

    def __call__(self, stage: str, fraction: float) -> None:
        if stage not in self.weights:
            return
        self.fractions[stage] = fraction
        self.stage = stage
        total = sum(w * self.fractions.get(s, 0.0) for s, w in self.weights.items())
        self.overall = max(self.overall, min(1.0, total / sum(self.weights.values())))
        now = time.monotonic()
        if now - self._written >= PROGRESS_EVERY_S:
            self.flush()
            self._written = now

    def flush(self) -> None:
        """Write the part's progress (and the job's) now."""
        stage = self.stage if self.part.kind == "merge" else None
        try:
            with self.sessions() as session:
                parts.record_progress(session, self.part, self.overall, stage)
        except Exception:  # noqa: BLE001 - progress is best effort
            log.warning(
                "job %s: cannot record the progress of %s", self.part.job_id, self.part.name
            )
