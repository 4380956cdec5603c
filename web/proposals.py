"""Corrections that spread inside one scan, for the viewer (issue 66, point 3): what a tab's
corrections teach, proposed for the rest of its scan by :func:`jointseg.adapt.spread.propose`.

The tab's corrections are its version's ``user_label`` (a saved version's file carries it) with
its unsaved edits over them; the labels proposed over are the tab's current ones. A proposal
takes seconds (the network's head is refitted), so the tab takes a :class:`Snapshot` under its
lock and :func:`make_proposal` runs in a worker thread on it alone. The network is loaded once
per viewer process, on the first proposal.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.adapt.spread import Proposal, propose
from jointseg.classes import CLASS_NAMES
from jointseg.exceptions import ConfigError, JointsegError
from jointseg.io import read_scan
from jointseg.labels.edits import EditList, apply_edits
from jointseg.labels.version import USER_LABEL_FIELD, user_labels_of
from jointseg.pipeline import load_predictor
from jointseg.pipeline.config import PipelineConfig
from web.editing import Columns

log = logging.getLogger(__name__)

#: What a press with nothing corrected is told.
NOTHING_CORRECTED = (
    "Correct some segments first: a proposal spreads your corrections to the segments like them."
)

_predictor: Any = None
_predictor_lock = threading.Lock()


class ProposalError(JointsegError):
    """Why no proposal could be made, in words for the viewer's user."""


def predictor() -> Any:
    """The bundled network, loaded on first use and kept for the process (0.3 s a load)."""
    global _predictor
    with _predictor_lock:
        if _predictor is None:
            try:
                _predictor = load_predictor(PipelineConfig().network)
            except (JointsegError, OSError, RuntimeError) as exc:
                log.warning("no network for proposals: %s", exc)
                raise ProposalError(f"No network to propose with: {exc}") from exc
        return _predictor


@dataclass(frozen=True, eq=False)
class Snapshot:
    """What a proposal is made from, copied from the tab when it is asked for."""

    path: Path
    columns: Columns
    labels: np.ndarray
    edits: EditList | None
    report: dict[str, Any] | None


def to_work_of(report: dict[str, Any] | None) -> np.ndarray | None:
    """The run's ``frame.to_work`` (the identity for a scan used as stored); None when the
    report does not say, and the frame is decided again."""
    frame = (report or {}).get("frame")
    if not isinstance(frame, dict):
        return None
    if "to_work" in frame:
        matrix = np.asarray(frame["to_work"], dtype=np.float64)
        if matrix.shape == (4, 4) and np.isfinite(matrix).all():
            return matrix
    return np.eye(4) if frame.get("identity") is True else None


def user_labels(snap: Snapshot, saved: np.ndarray | None) -> np.ndarray:
    """The tab's corrections per row: the version's ``user_label`` with the unsaved edits over
    it (-1 where none)."""
    n = snap.columns.segment.shape[0]
    base = np.full(n, -1, np.int16) if saved is None else saved.astype(np.int16)
    if snap.edits is None:
        return base
    cols = snap.columns
    outcome = apply_edits(
        snap.edits, machine_labels=cols.fused, user_label=base, segment=cols.segment, xyz=cols.xyz
    )
    return outcome.user_label


def make_proposal(snap: Snapshot) -> Proposal:
    """The proposal of the snapshot's corrections (may be empty).

    Raises
    ------
    ProposalError
        Nothing is corrected, the result cannot be read or no network can be loaded.
    """
    try:
        scan = read_scan(snap.path)
    except (JointsegError, OSError) as exc:
        raise ProposalError(f"Cannot read the result: {exc}") from exc
    if len(scan) != snap.labels.shape[0]:
        raise ProposalError("The result changed on disk; reload the job and propose again.")
    user = user_labels(snap, user_labels_of(scan))
    if not (user >= 0).any():
        raise ProposalError(NOTHING_CORRECTED)
    result = scan.with_fields(fused_label=snap.labels.astype(np.int32), **{USER_LABEL_FIELD: user})
    net = predictor()
    try:
        return propose(result, net, to_work=to_work_of(snap.report))
    except (ConfigError, ValueError, RuntimeError) as exc:
        log.warning("proposal of %s failed: %s", snap.path.name, exc)
        raise ProposalError(f"No proposal: {exc}") from exc


def describe(proposal: Proposal) -> str:
    """``12 segments (3,456 points): beam 10, column 2``, or that nothing was found."""
    if len(proposal.segments) == 0:
        return "Nothing to propose: no other segment looks like the ones you corrected."
    classes, counts = np.unique(proposal.labels, return_counts=True)
    pairs = zip(classes.tolist(), counts.tolist(), strict=True)
    parts = ", ".join(f"{CLASS_NAMES[c]} {n}" for c, n in pairs)
    n, points = len(proposal.segments), int(proposal.points.sum())
    return f"{n} segment{'s' * (n > 1)} ({points:,} points): {parts}"
