"""The evidence vote (beyond the paper): a point takes its voting unit's label only where the
unit's evidence outweighs the network's own confidence at the point.

On real scans a segment's majority is often wrong for part of it (a board inside its wall plane,
clutter on a table), and a strong network is mostly right where it is confident, so a hard
majority rule (eq. 7) destroys more than it repairs. Here each point's class scores are

    log p_i(c) + w * log q_U(c)

with p_i the network's probabilities at the point and q_U the mean probabilities over its voting
unit U (its segment cut into cubic cells, so a unit stays local even in a whole wall plane). The
segment can only flip a point the network was unsure about, and only towards a class the network
gave that point some support: a confident point (p 0.95 against 0.03) needs a unit whose
evidence is (0.95 / 0.03)^(1 / w) times stronger, which a pure unit has and a mixed one lacks.
With hard labels (no probabilities) p_i is the one-hot label smoothed by ``HARD_LABEL_SMOOTHING``.
"""

from __future__ import annotations

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.grouping import group_sums

#: Floor under probabilities before the logarithm: a class the network gave nothing is very
#: unlikely, not impossible.
EPS = 1e-3
#: Probability mass a hard label spreads over the other classes when no probabilities are given.
HARD_LABEL_SMOOTHING = 0.2


def point_probs(labels: np.ndarray, probs: np.ndarray | None) -> np.ndarray:
    """The network's probabilities, or smoothed one-hot labels when there are none."""
    if probs is not None:
        return np.asarray(probs, dtype=np.float32)
    out = np.full((len(labels), NUM_CLASSES), HARD_LABEL_SMOOTHING / NUM_CLASSES, np.float32)
    out[np.arange(len(labels)), labels] += 1.0 - HARD_LABEL_SMOOTHING
    return out


def unit_means(unit: np.ndarray, n_units: int, probs: np.ndarray) -> np.ndarray:
    """Mean probability per voting unit, shape (n_units, C)."""
    sums = group_sums(unit, n_units, probs)
    counts = np.bincount(unit, minlength=n_units)
    return sums / np.maximum(counts, 1)[:, None]


def evidence_labels(
    unit: np.ndarray, n_units: int, labels: np.ndarray, probs: np.ndarray, *, weight: float
) -> tuple[np.ndarray, np.ndarray]:
    """Fused labels and each unit's mean probabilities.

    Parameters
    ----------
    unit : ndarray of shape (N,), int
        Voting unit 0..n_units-1 of every point.
    n_units : int
    labels : ndarray of shape (N,), int
        The network's labels, kept wherever the unit does not change the point's decision
        (they may differ from the argmax of ``probs``, e.g. after a K-neighbour transfer).
    probs : ndarray of shape (N, C)
        Per-point class probabilities (see :func:`point_probs`).
    weight : float
        w: how much a unit's evidence counts against the point's own (0 keeps the network's
        argmax).

    Returns
    -------
    labels : ndarray of shape (N,), int64
    means : ndarray of shape (n_units, C), float64
    """
    means = unit_means(unit, n_units, probs)
    own_best = probs.argmax(axis=1)
    fused = np.asarray(labels, dtype=np.int64).copy()
    # a class that is best for both the point and its unit is best for their sum: only points
    # whose unit prefers another class can change, so only they are scored
    open_ = np.flatnonzero(means.argmax(axis=1)[unit] != own_best)
    if len(open_) and weight > 0:
        scores = np.log(probs[open_] + EPS)
        scores += weight * np.log(means[unit[open_]] + EPS).astype(np.float32)
        decided = scores.argmax(axis=1)
        moved = decided != own_best[open_]
        fused[open_[moved]] = decided[moved]
    return fused, means
