"""Voxel grids: grouping points by cell, the shared tool of sub-sampling in every stage."""

from __future__ import annotations

import numpy as np

from jointseg.grouping import (
    cell_keys,
    compact_ids,
    group_sums,
    majority_label,
    sorted_distinct,
)


def voxel_index(xyz: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Group points by cubic cells of side ``voxel`` (metres).

    Returns
    -------
    inverse : ndarray of shape (N,), int64
        Cell of each point, 0..V-1.
    centroids : ndarray of shape (V, 3)
        Mean position of each cell's points.
    """
    keys, _ = cell_keys(xyz, voxel)
    return cell_centroids(xyz, keys)


def cell_centroids(xyz: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`voxel_index` of points whose cell keys (:func:`jointseg.grouping.cell_keys`) are
    already known: the cell of each point, 0..V-1, and each cell's mean position."""
    _, inverse = compact_ids(keys)
    counts = np.bincount(inverse)
    return inverse, group_sums(inverse, len(counts), xyz) / counts[:, None]


def voxel_count(xyz: np.ndarray, voxel: float) -> tuple[int, np.ndarray]:
    """How many cells of side ``voxel`` the points occupy, and their cell keys: the count is
    one sort, without renumbering the points or averaging them."""
    keys, _ = cell_keys(xyz, voxel)
    return len(sorted_distinct(keys)), keys


def cell_means(values: np.ndarray, inverse: np.ndarray, cells: int) -> np.ndarray:
    """Mean of per-point ``values`` (N, C) in each cell, shape (cells, C)."""
    size = np.maximum(np.bincount(inverse, minlength=cells), 1)
    return group_sums(inverse, cells, values) / size[:, None]


def cell_majority(labels: np.ndarray, inverse: np.ndarray, cells: int) -> np.ndarray:
    """Most frequent non-negative label in each cell (-1 where a cell has none)."""
    return majority_label(inverse, cells, labels).astype(np.int32)
