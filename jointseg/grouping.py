"""Group-by kernels on integer ids, shared by the voxels, the fusion, the metrics, the
clustering and the viewer.

Every stage groups points (by voxel, segment, cell or region) and then renumbers the groups,
counts labels per group or sums values per group. These few kernels do that once, in linear
time with ``np.bincount`` and no Python loop over points, so the stages agree to the bit on
what a voxel, a renumbering or a majority is. Numpy only: no torch, no scipy.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

#: Ids spanning at most this many times their count are renumbered through a lookup table
#: (linear); sparser ids are sorted, which needs no table the size of the span. Past about four
#: the table's prefix sum costs more than the one sort of :func:`_sorted_ranks`.
DENSE_SPAN_FACTOR = 4


def compact_ids(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct ids and every id renumbered to 0..S-1, so groups can index arrays.

    Same result as ``np.unique(ids, return_inverse=True)`` (ranks keep the ids' order), in
    linear time unless the ids are very sparse.

    Parameters
    ----------
    ids : ndarray of shape (N,), int
        Any integers (negative ones too).

    Returns
    -------
    distinct : ndarray of shape (S,), int64
        The distinct ids, sorted.
    inverse : ndarray of shape (N,), int64
        Index into ``distinct`` of every id.
    """
    ids = np.asarray(ids)
    if ids.ndim != 1:
        raise ValueError(f"ids must be 1-D, got shape {ids.shape}")
    if len(ids) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    if not np.issubdtype(ids.dtype, np.integer):
        raise TypeError(f"ids must be integers, got dtype {ids.dtype}")
    ids = ids.astype(np.int64, copy=False)
    lo, hi = int(ids.min()), int(ids.max())
    if hi - lo >= DENSE_SPAN_FACTOR * len(ids):
        return _sorted_ranks(ids, lo, hi)
    offset = ids - lo if lo else ids
    present = np.zeros(hi - lo + 1, dtype=bool)
    present[offset] = True
    # ranks below 2**31 fit int32: half the memory traffic over a table that may be 4 N long
    rank_type = np.int32 if len(present) < 2**31 else np.int64
    rank: np.ndarray = np.cumsum(present, dtype=rank_type)
    rank -= 1
    return np.flatnonzero(present).astype(np.int64) + lo, rank[offset].astype(np.int64)


def _sorted_ranks(ids: np.ndarray, lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`compact_ids` of sparse ids by one sort of the ids packed with their positions.

    Sorting the packed values (id above, position below) gives the order ``np.unique`` finds
    with an argsort at a fraction of its cost, and the same distinct ids and ranks.
    """
    n = len(ids)
    bits = max(1, (n - 1).bit_length())
    if (hi - lo) >> (62 - bits):  # the packed value would not fit an int64
        distinct, inverse = np.unique(ids, return_inverse=True)
        return distinct.astype(np.int64), inverse.reshape(-1).astype(np.int64)
    packed = ids - lo
    packed <<= bits
    packed |= np.arange(n, dtype=np.int64)
    packed.sort()
    order = packed & ((1 << bits) - 1)
    packed >>= bits  # the sorted ids, less lo
    first = np.empty(n, dtype=bool)
    first[0] = True
    np.not_equal(packed[1:], packed[:-1], out=first[1:])
    rank = np.cumsum(first, dtype=np.int64)
    rank -= 1
    inverse = np.empty(n, dtype=np.int64)
    inverse[order] = rank
    distinct = packed[first]
    distinct += lo
    return distinct, inverse


def sorted_distinct(ids: np.ndarray) -> np.ndarray:
    """``np.unique(ids)`` of integer ids (the distinct ids, sorted, in their dtype) by one sort.

    numpy 2.3 and later find plain distinct values with a hash table, which on a million ids
    costs some thirty times the sort.
    """
    ids = np.asarray(ids)
    if not np.issubdtype(ids.dtype, np.integer):
        raise TypeError(f"ids must be integers, got dtype {ids.dtype}")
    ordered = np.sort(ids, axis=None)
    if len(ordered) < 2:
        return ordered
    first = np.empty(len(ordered), dtype=bool)
    first[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    return ordered[first]


def cell_keys(
    xyz: np.ndarray,
    size: float,
    *,
    origin: np.ndarray | None = None,
    aligned: bool = False,
) -> tuple[np.ndarray, int]:
    """Flat key of the cubic cell of side ``size`` each point falls in, so points can be
    grouped by cell with one integer per point.

    Keys run row-major over the cells of the points' bounding box from ``origin``; combine them
    with another id as ``other * n_keys + key``.

    Parameters
    ----------
    xyz : ndarray of shape (N, D)
        Coordinates (D = 3 for voxels).
    size : float
        Cell side, in the units of ``xyz``.
    origin : ndarray of shape (D,), optional
        Corner of cell 0; no coordinate may lie below it. Default: the per-axis minimum.
    aligned : bool
        Cells on the absolute grid (cell ``floor(x / size)``) instead of one starting at the
        points' minimum, so any subset of the points falls into the same cells as the whole
        set does: a scan fused tile by tile groups its points as the whole scan would.

    Returns
    -------
    keys : ndarray of shape (N,), int64
    n_keys : int
        Number of cells in the bounding box: every key is below it.
    """
    xyz = np.asarray(xyz)
    if xyz.ndim != 2:
        raise ValueError(f"xyz must have shape (N, D), got {xyz.shape}")
    if len(xyz) == 0:
        return np.zeros(0, dtype=np.int64), 0
    # floor((xyz - lo) / size) column by column, each column's values and dtype as the whole
    # array's: a scan of millions of points then needs temporaries of one column, not three
    lo = None
    if not aligned:
        lo = _column_extremes(xyz, np.min) if origin is None else np.asarray(origin)
        lo = np.broadcast_to(lo, (xyz.shape[1],))
    keys = np.zeros(len(xyz), dtype=np.int64)
    dims = np.ones(xyz.shape[1], dtype=np.int64)
    for axis in range(xyz.shape[1]):
        column = xyz[:, axis]
        if lo is None:
            cells = _floor_cells(column / size)
            cells -= cells.min()
        else:
            shifted = column - lo[axis]
            same = shifted.dtype.kind == "f" and np.result_type(shifted, size) == shifted.dtype
            cells = _floor_cells(np.divide(shifted, size, out=shifted if same else None))
            if origin is not None and cells.min() < 0:
                raise ValueError("origin must not lie above any point")
        dims[axis] = cells.max() + 1
        keys *= dims[axis]
        keys += cells
    return keys, int(dims.prod())


def _column_extremes(values: np.ndarray, extreme: Callable[..., Any]) -> np.ndarray:
    """``extreme(values, axis=0)`` (np.min or np.max) column by column: numpy reduces an
    (N, 3) array along its long axis a dozen times slower than three strided columns."""
    return np.array([extreme(values[:, c]) for c in range(values.shape[1])], dtype=values.dtype)


def _floor_cells(scaled: np.ndarray) -> np.ndarray:
    """``np.floor(scaled).astype(np.int64)``, flooring in place (``scaled`` is a temporary)."""
    if np.issubdtype(scaled.dtype, np.floating):
        np.floor(scaled, out=scaled)
        return scaled.astype(np.int64)
    return np.floor(scaled).astype(np.int64)


def rows_by_id(ids: np.ndarray) -> list[np.ndarray]:
    """The rows of each id >= 0, one ascending array per id, ids in ascending order (negative
    ids are none): one sort, not a scan of the array per id."""
    valid = np.flatnonzero(ids >= 0)
    if valid.size == 0:
        return []
    order = valid[np.argsort(ids[valid], kind="stable")]
    bounds = np.flatnonzero(np.diff(ids[order])) + 1
    return np.split(order, bounds)


def group_sums(group: np.ndarray, n_groups: int, values: np.ndarray) -> np.ndarray:
    """Column sums of ``values`` per group (soft votes, colour or position totals).

    Parameters
    ----------
    group : ndarray of shape (N,), int
        Group 0..n_groups-1 of every row.
    n_groups : int
    values : ndarray of shape (N, C)

    Returns
    -------
    ndarray of shape (n_groups, C), float64
    """
    values = np.asarray(values)
    if values.ndim != 2:
        raise ValueError(f"values must have shape (N, C), got {values.shape}")
    if values.shape[1] == 0:
        return np.zeros((n_groups, 0))
    return np.column_stack(
        [
            np.bincount(group, weights=values[:, c], minlength=n_groups)
            for c in range(values.shape[1])
        ]
    )


def group_quantiles(
    group: np.ndarray, n_groups: int, values: np.ndarray, qs: tuple[float, ...]
) -> list[np.ndarray]:
    """Per-group quantiles of ``values`` from one sort: for each ``q`` of ``qs``, the lower
    element at ``q`` of each group's sorted values (NaN for an empty group).

    Parameters
    ----------
    group : ndarray of shape (N,), int
        Group 0..n_groups-1 of every value.
    n_groups : int
    values : ndarray of shape (N,)
    qs : tuple of float in [0, 1]

    Returns
    -------
    list of ndarray of shape (n_groups,), one per ``q``
    """
    counts = np.bincount(group, minlength=n_groups)
    if len(values) == 0:
        return [np.full(n_groups, np.nan) for _ in qs]
    ordered = _sorted_within_groups(np.asarray(group), np.asarray(values))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = []
    for q in qs:
        pos = starts + np.floor(q * np.maximum(counts - 1, 0)).astype(np.int64)
        out.append(np.where(counts > 0, ordered[np.minimum(pos, len(values) - 1)], np.nan))
    return out


def _sorted_within_groups(group: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values[np.lexsort((values, group))]`` in a third of the time: the values by rank (one
    argsort), then packed with their group and sorted as integers.

    Equal values may come in any order without changing the result, unless they differ in
    their bits: -0.0 beside 0.0, or NaNs; for those the value sort is the stable one, as in
    lexsort.
    """
    n = len(values)
    bits = max(1, (n - 1).bit_length())
    top = int(group.max()) if n else 0
    simple = group.dtype.kind in "iu" and values.dtype.kind in "iuf"
    if not simple or int(group.min()) < 0 or top >> (62 - bits):
        return values[np.lexsort((values, group))]
    ambiguous = values.dtype.kind == "f" and bool(
        np.isnan(values).any() or np.any((values == 0) & np.signbit(values))
    )
    by_value = np.argsort(values, kind="stable" if ambiguous else None)
    rank = np.empty(n, dtype=np.int64)
    rank[by_value] = np.arange(n)
    packed = group.astype(np.int64) << bits
    packed |= rank
    packed.sort()
    packed &= (1 << bits) - 1
    return values[by_value[packed]]


def label_histogram(
    group: np.ndarray,
    n_groups: int,
    labels: np.ndarray,
    n_labels: int | None = None,
    *,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Count (or weigh) each label in each group: the vote behind every majority.

    Negative labels are unlabelled points and are not counted.

    Parameters
    ----------
    group : ndarray of shape (N,), int
        Group 0..n_groups-1 of every point.
    n_groups : int
    labels : ndarray of shape (N,), int
    n_labels : int, optional
        Number of label columns; default: the largest label + 1 (1 when none is counted).
    weights : ndarray of shape (N,), optional
        Weight of each point's vote; default 1.

    Returns
    -------
    ndarray of shape (n_groups, n_labels)
        int64 counts, or float64 sums of ``weights``.
    """
    group = np.asarray(group).astype(np.int64, copy=False)
    labels = np.asarray(labels)
    if group.shape != labels.shape or group.ndim != 1:
        raise ValueError(
            f"group and labels must be 1-D of one length, got {group.shape}, {labels.shape}"
        )
    if len(labels) and labels.min() < 0:
        valid = labels >= 0
        group, labels = group[valid], labels[valid]
        weights = None if weights is None else np.asarray(weights)[valid]
    top = int(labels.max()) if len(labels) else -1
    if n_labels is None:
        n_labels = top + 1 if top >= 0 else 1
    elif top >= n_labels:
        raise ValueError(f"label {top} does not fit in {n_labels} label columns")
    counts = np.bincount(group * n_labels + labels, weights=weights, minlength=n_groups * n_labels)
    return counts.reshape(n_groups, n_labels)


def majority_label(
    group: np.ndarray,
    n_groups: int,
    labels: np.ndarray,
    n_labels: int | None = None,
    *,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """Most frequent (or heaviest) non-negative label of each group; ties go to the smaller label.

    Parameters are those of :func:`label_histogram`.

    Returns
    -------
    ndarray of shape (n_groups,), int64
        -1 where a group has no counted vote.
    """
    counts = label_histogram(group, n_groups, labels, n_labels, weights=weights)
    return np.where(counts.sum(axis=1) > 0, counts.argmax(axis=1), -1)
