"""What a network hands back: labels and probabilities per point, or per-cell sums of a
scan's crops. Its own module so the Predictor protocol (``backends``) and every backend
name them without importing one another."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class NetworkResult:
    """Labels and class probabilities for every input point.

    Attributes
    ----------
    labels : ndarray of shape (N,), int32
    probs : ndarray of shape (N, 13), float32
        Averaged softmax outputs; rows sum to 1.
    """

    labels: np.ndarray
    probs: np.ndarray
    crops: int
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def confidence(self) -> np.ndarray:
        """Probability of the predicted class per point."""
        return self.probs.max(axis=1)


@dataclass(frozen=True)
class CellSums:
    """Summed softmax outputs per sub-sampled cell, from some of a scan's crops.

    Attributes
    ----------
    ids : ndarray of shape (K,), int64
        Packed cell ids (:func:`jointseg.network.anchored.cell_ids`), ascending.
    sums : ndarray of shape (K, 13), float64
    seen : ndarray of shape (K,), float64
        Crops that saw each cell.
    point_cell : ndarray of shape (N,), int64
        The cell whose outputs each input point takes (its own, or its nearest sub-sampled
        point's: ``RandLANetParams.projection``).
    """

    ids: np.ndarray
    sums: np.ndarray
    seen: np.ndarray
    point_cell: np.ndarray
