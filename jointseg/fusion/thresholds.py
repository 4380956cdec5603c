"""The learned vote's thresholds: what the network's output says of each class over a scan
(:class:`ClassTally`) and, from it, the least P(right) at which each offer is taken so that the
expected mIoU rises (:func:`offer_thresholds`).

Why apart: tiled runs tally each tile and add the tallies (``pipeline/tiled``), without the
offers or the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.fusion.offers import EPS, _at

#: :class:`ClassTally` sums the probabilities in blocks of this many rows (their rounding is
#: the model's thresholds'; the name is from when the entropy was taken in such blocks too).
ENTROPY_BLOCK = 1 << 18
#: Rows of a block :class:`ClassTally` converts to float64 at once.
TALLY_ROWS = 1 << 13
#: :func:`offer_thresholds` counts every class as at least this share of the scan (a class
#: of a few points would otherwise ask for certainty, or be joined on no evidence).
MIN_CLASS_SHARE = 0.001
#: :meth:`ClassTally.ious` takes no class's expected IoU as lower than this (a class the
#: network seems never to find right would otherwise hold its points against any evidence).
MIN_EXPECTED_IOU = 0.4


@dataclass(frozen=True)
class ClassTally:
    """What the network's output says of each class over a scan, for :func:`offer_thresholds`:
    the points it gave the class, the class's probability summed over every point (the points
    expected truly of the class) and, over the points it gave the class, that probability
    summed (those expected right). Parts of a scan (tiles) add up.

    Attributes
    ----------
    counts, expected, agreed : ndarray of shape (C,), float64
    """

    counts: np.ndarray
    expected: np.ndarray
    agreed: np.ndarray

    @classmethod
    def of(cls, labels: np.ndarray, probs: np.ndarray) -> ClassTally:
        """The tally of points labelled ``labels`` (N,) with probabilities ``probs`` (N, C)."""
        labels = np.asarray(labels, dtype=np.int64)
        n_classes = probs.shape[1]
        own = _at(probs, np.arange(len(labels)), labels)
        return cls(
            counts=np.bincount(labels, minlength=n_classes).astype(np.float64),
            expected=_expected(probs),
            agreed=np.bincount(labels, weights=own, minlength=n_classes),
        )

    @classmethod
    def empty(cls, n_classes: int = NUM_CLASSES) -> ClassTally:
        """The tally of no points."""
        return cls(np.zeros(n_classes), np.zeros(n_classes), np.zeros(n_classes))

    def __add__(self, other: ClassTally) -> ClassTally:
        return ClassTally(
            self.counts + other.counts,
            self.expected + other.expected,
            self.agreed + other.agreed,
        )

    def _union(self) -> np.ndarray:
        """Each class's expected union of truth and labels, as tallied."""
        return self.expected + self.counts - self.agreed

    def unions(self) -> np.ndarray:
        """Each class's expected union of truth and labels (:func:`at_least_min_share`)."""
        return at_least_min_share(self._union(), float(self.counts.sum()))

    def ious(self) -> np.ndarray:
        """Each class's expected IoU, at least :data:`MIN_EXPECTED_IOU`."""
        union = self._union()
        iou = np.where(union > 0, self.agreed / np.maximum(union, 1e-12), 1.0)
        return np.clip(iou, MIN_EXPECTED_IOU, 1.0)


def _expected(probs: np.ndarray) -> np.ndarray:
    """Each class's probability summed over the rows of ``probs`` (N, C) in float64: per block
    of ENTROPY_BLOCK rows, row after row (as numpy sums a C-contiguous block's first axis), the
    blocks' sums then added. A block is converted a part of TALLY_ROWS rows at a time into one
    small buffer whose first row carries the block's sum so far, and summed by ``np.bincount``
    over the flat buffer with each value's class as its bin (it adds in order, the classes side
    by side), so the sums round as over the whole block."""
    n, n_classes = probs.shape
    expected = np.zeros(n_classes)
    buf = np.empty((min(n, TALLY_ROWS) + 1, n_classes))
    bins = np.tile(np.arange(n_classes), len(buf))
    for start in range(0, n, ENTROPY_BLOCK):
        stop = min(start + ENTROPY_BLOCK, n)
        block_sum: np.ndarray = np.zeros(n_classes)
        for part in range(start, stop, TALLY_ROWS):
            rows = min(TALLY_ROWS, stop - part)
            buf[0] = block_sum
            np.copyto(buf[1 : rows + 1], probs[part : part + rows])
            size = (rows + 1) * n_classes
            block_sum = np.bincount(bins[:size], buf.reshape(-1)[:size], n_classes)
        expected += block_sum
    return expected


def at_least_min_share(sizes: np.ndarray, points: float) -> np.ndarray:
    """Class sizes, each at least :data:`MIN_CLASS_SHARE` of a scan of ``points`` (a class of a
    few points would otherwise ask for certainty, or be joined on no evidence)."""
    return np.maximum(sizes, MIN_CLASS_SHARE * max(points, 1.0))


def offer_thresholds(
    tally: ClassTally,
    own: np.ndarray,
    offer: np.ndarray,
    threshold: float,
    metric_iou: float | str,
) -> np.ndarray:
    """The least P(right) at which each offer is taken, so that a taken offer raises the
    expected mIoU (the metric every class counts in alike).

    Moving one point from class a (``own``) to b (``offer``) changes the IoUs, to first order
    in the classes' unions U and IoUs k, by ``k_a / U_a + 1 / U_b`` where the offer is right
    and by ``-(1 / U_a + k_b / U_b)`` where the network was. The offer pays where its odds
    exceed the ratio of the two, times the odds of ``threshold``: out of a class the scan has
    little of (a board in its wall) it asks for more, into one for less, and out of a class
    the network finds poorly (k_a small: taking its false points away gains it little, taking
    its true ones loses it much) for more still.

    ``metric_iou`` "auto": U and k are those the network's own probabilities expect
    (:meth:`ClassTally.unions`, :meth:`ClassTally.ious`). A number: one guess of k for all
    classes, U the network's counts (at least :data:`MIN_CLASS_SHARE` of the scan); 1 gives
    ``threshold`` everywhere."""
    if metric_iou == "auto":
        u, k = tally.unions(), tally.ious()
    elif float(metric_iou) >= 1:
        return np.full(len(own), threshold, dtype=np.float64)
    else:
        u = at_least_min_share(tally.counts, float(tally.counts.sum()))
        k = np.full(len(u), float(metric_iou))
    ua, ub, ka, kb = u[own], u[offer], k[own], k[offer]
    base = threshold / max(1.0 - threshold, EPS)
    odds = base * (1 / ua + kb / ub) / (ka / ua + 1 / ub)
    return odds / (1 + odds)
