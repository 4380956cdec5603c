"""Voxel grids: grouping points by cell, the shared tool of sub-sampling in every stage."""

from __future__ import annotations

import numpy as np


def voxel_index(xyz: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Group points by cubic cells of side ``voxel`` (metres).

    Returns
    -------
    inverse : ndarray of shape (N,), int64
        Cell of each point, 0..V-1.
    centroids : ndarray of shape (V, 3)
        Mean position of each cell's points.
    """
    keys = np.floor((xyz - xyz.min(axis=0)) / voxel).astype(np.int64)
    dims = keys.max(axis=0) + 1
    flat = (keys[:, 0] * dims[1] + keys[:, 1]) * dims[2] + keys[:, 2]
    _, inverse = np.unique(flat, return_inverse=True)
    counts = np.bincount(inverse)
    centroids = np.column_stack(
        [np.bincount(inverse, weights=xyz[:, d]) / counts for d in range(3)]
    )
    return inverse, centroids


def cell_means(values: np.ndarray, inverse: np.ndarray, cells: int) -> np.ndarray:
    """Mean of per-point ``values`` (N, C) in each cell, shape (cells, C)."""
    size = np.maximum(np.bincount(inverse, minlength=cells), 1)
    return np.column_stack(
        [
            np.bincount(inverse, weights=values[:, c], minlength=cells) / size
            for c in range(values.shape[1])
        ]
    )


def cell_majority(labels: np.ndarray, inverse: np.ndarray, cells: int) -> np.ndarray:
    """Most frequent non-negative label in each cell (-1 where a cell has none)."""
    valid = labels >= 0
    n_cls = int(labels.max()) + 1 if valid.any() else 1
    counts = np.bincount(inverse[valid] * n_cls + labels[valid], minlength=cells * n_cls).reshape(
        cells, n_cls
    )
    return np.where(counts.sum(axis=1) > 0, counts.argmax(axis=1), -1).astype(np.int32)
