"""Corrections that spread inside one scan (issue 66, point 3): what a user's corrected
segments teach, proposed for the segments like them that the user has not reached yet.

The head is fitted to this scan's corrections alone (its uncorrected points held to the
network's answer, no generated rooms: the proposal is about this scan only), then each segment
nobody corrected is proposed the class the fitted head gives most of its points, when that
class is one the user gave, differs from the segment's current label and holds at least
``min_share`` of its points. The user accepts the proposal (it becomes edits, a new version) or
leaves it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from jointseg.adapt.examples import scan_examples
from jointseg.adapt.head import AdaptParams, fit_head
from jointseg.classes import NUM_CLASSES
from jointseg.labels.edits import version_labels
from jointseg.labels.version import machine_labels, user_labels_of
from jointseg.scan import Scan

#: The head's fit for a proposal: this scan only, fewer steps (a proposal is asked for often).
SPREAD = AdaptParams(steps=150, replay_rooms=0)


@dataclass(frozen=True)
class Proposal:
    """Segments proposed a class: ``segments`` (S,) ids, ``labels`` (S,) the classes proposed,
    ``points`` (S,) their sizes; :meth:`edits` as the edit list that accepts them."""

    segments: np.ndarray
    labels: np.ndarray
    points: np.ndarray

    def edits(self) -> list[dict[str, Any]]:
        by_class: dict[int, list[int]] = {}
        for seg, cls in zip(self.segments.tolist(), self.labels.tolist(), strict=True):
            by_class.setdefault(int(cls), []).append(int(seg))
        return [{"segments": segs, "label": cls} for cls, segs in sorted(by_class.items())]


def segment_votes(segment: np.ndarray, labels: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Each segment's commonest label and that label's share of its points."""
    keep = segment >= 0
    counts = np.bincount(
        segment[keep] * NUM_CLASSES + labels[keep], minlength=n * NUM_CLASSES
    ).reshape(n, NUM_CLASSES)
    total = np.maximum(counts.sum(axis=1), 1)
    return counts.argmax(axis=1), counts.max(axis=1) / total


def propose(
    result: Scan,
    predictor: Any,
    *,
    to_work: np.ndarray | None = None,
    min_share: float = 0.6,
    params: AdaptParams = SPREAD,
) -> Proposal:
    """The segments of ``result`` (a labels version with ``user_label``) that its corrections
    teach a new class; empty when nothing is corrected."""
    user = user_labels_of(result)
    segment = np.asarray(result.fields["segment"], dtype=np.int64)
    empty = Proposal(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64))
    if user is None or not (user >= 0).any():
        return empty
    ex = scan_examples(predictor, result, user, to_work=to_work, seed=params.seed)
    head, _ = fit_head(predictor.model.head, ex.examples, params)
    with torch.inference_mode():
        sub = head(torch.from_numpy(ex.examples.features)).argmax(dim=-1).numpy()
    labels = version_labels(machine_labels(result), user).astype(np.int64)
    taught = labels.copy()  # strays: as they are
    taught[ex.rows] = sub[ex.nearest]
    n = int(segment.max()) + 1
    current, _ = segment_votes(segment, labels, n)
    new, share = segment_votes(segment, taught, n)
    touched = np.zeros(n, bool)
    touched[segment[(user >= 0) & (segment >= 0)]] = True
    given = np.zeros(NUM_CLASSES, bool)
    given[np.unique(user[user >= 0]).astype(np.int64)] = True
    chosen = ~touched & given[new] & (new != current) & (share >= min_share)
    sizes = np.bincount(segment[segment >= 0], minlength=n)
    ids = np.flatnonzero(chosen & (sizes > 0))
    return Proposal(ids, new[ids], sizes[ids])
