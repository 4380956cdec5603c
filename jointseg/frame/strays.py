"""Stray points: returns through windows and off mirrors, metres outside the room.

A handful of them moves every normalisation that looks at extremes (the network's height above
the lowest point, the geometry's bounding-box faces). Two rules, in the levelled metric frame:
points separated from the scan's bulk along an axis by an empty gap, and points with almost no
neighbours. Both are cheap: a histogram per axis and a count per cell, a few passes over the
points' columns and no sort of them (the stage runs on every point of a scan before anything
else).
"""

from __future__ import annotations

import numpy as np

#: Histogram bins (m) and the empty gap (m) that cuts a stretch of points off the bulk.
BIN_M = 0.1
GAP_M = 1.0
#: A histogram bin with fewer than this share of the points counts as empty.
OCCUPIED_SHARE = 1e-4
#: Isolation: a point whose 3x3x3 block of cells of this size (m) holds fewer points than this
#: is stray.
CELL_M = 0.3
MIN_NEIGHBOURS = 3
#: A lonely point this far (m) outside the box of the other points is stray.
BOX_TOLERANCE_M = 0.1
#: More than this share of the scan is never called stray: that is structure, not noise.
MAX_SHARE = 0.05
#: Cell grids up to this many cells (or as many as the points, when more) are counted in a dense
#: array; a sparser grid (strays far out make the box huge) sorts its cells' keys.
DENSE_CELLS = 1 << 21


def bulk_mask(values: np.ndarray) -> np.ndarray:
    """Points within the stretch of ``values`` that holds the median, where no gap of
    :data:`GAP_M` without a share of the points interrupts it."""
    cut = _bulk_cut(values)
    if cut is None:
        return np.ones(len(values), dtype=bool)
    idx, first, last = cut
    return (idx > first) & (idx < last)


def _bulk_cut(values: np.ndarray) -> tuple[np.ndarray, int, int] | None:
    """Each value's histogram bin and the open range of bins of the bulk (``first < bin <
    last``); None when the bulk holds every value, which the histogram tells without another
    pass over the points."""
    lo, hi = float(values.min()), float(values.max())
    if hi - lo <= GAP_M:
        return None
    bins = int(np.ceil((hi - lo) / BIN_M)) + 1
    idx = _bins(values, lo)
    counts = np.bincount(idx, minlength=bins)
    # a bin holding a few scattered strays is as good as empty: it takes a share of the scan
    occupied = counts >= max(2.0, OCCUPIED_SHARE * len(values))
    start = stop = int((median_by_bins(values, idx, counts) - lo) / BIN_M)
    gap = int(np.ceil(GAP_M / BIN_M))
    # extend both ways while an occupied bin lies within the gap
    occ = np.flatnonzero(occupied)
    left = occ[occ <= start]
    right = occ[occ >= stop]
    if len(left):
        jumps = np.flatnonzero(np.diff(left[::-1]) < -gap)
        start = int(left[::-1][jumps[0]] if len(jumps) else left[0])
    if len(right):
        jumps = np.flatnonzero(np.diff(right) > gap)
        stop = int(right[jumps[0]] if len(jumps) else right[-1])
    # sparse points within a gap of the bulk's ends belong to it (a wall's last few returns)
    first, last = start - gap, stop + gap
    if first < 0 and last > len(counts) - 1:
        return None
    return idx, first, last


def _bins(values: np.ndarray, lo: float) -> np.ndarray:
    """``((values - lo) / BIN_M).astype(int64)`` through one scratch array."""
    scratch = np.subtract(values, lo)
    np.divide(scratch, BIN_M, out=scratch)
    return scratch.astype(np.int64)


def median_by_bins(values: np.ndarray, idx: np.ndarray, counts: np.ndarray) -> np.floating:
    """``np.median(values)``, bit for bit, from the values' histogram bins (``idx``, monotone
    in the values, with ``counts``): the two middle ranks' bins found by the counts and only
    their values partitioned, not the whole array."""
    n = len(values)
    ends = np.cumsum(counts)
    ranks = ((n - 1) // 2, n // 2)  # one rank twice for an odd count: its mean is itself
    bins = np.searchsorted(ends, ranks, side="right")
    middle = []
    for b in sorted(set(bins.tolist())):
        inside = values[np.flatnonzero(idx == b)]
        below = int(ends[b]) - len(inside)
        kth = sorted({r - below for r, rb in zip(ranks, bins, strict=True) if rb == b})
        part = np.partition(inside, kth)
        middle += [part[r - below] for r, rb in zip(ranks, bins, strict=True) if rb == b]
    out: np.floating = np.median(np.array(middle, dtype=values.dtype))
    return out


def isolated_mask(xyz: np.ndarray) -> np.ndarray:
    """Points with fewer than :data:`MIN_NEIGHBOURS` points in their 27 surrounding cells."""
    return _isolated(np.ascontiguousarray(np.asarray(xyz).T))


def _isolated(columns: np.ndarray) -> np.ndarray:
    """:func:`isolated_mask` of the points' coordinate columns, (3, N): each point's cell
    counted, the counts of each cell's 27-block summed on a dense grid (a sort of the keys
    where the grid is too sparse for one), and read back per point."""
    lo = columns.min(axis=1)
    cells = [np.floor((columns[a] - lo[a]) / CELL_M).astype(np.int64) + 1 for a in range(3)]
    dims = np.array([int(c.max()) + 2 for c in cells], dtype=np.int64)
    key = (cells[0] * dims[1] + cells[1]) * dims[2] + cells[2]
    size = int(np.prod(dims))
    if size > max(DENSE_CELLS, len(key)):
        return _isolated_sparse(key, dims)
    counts = np.bincount(key, minlength=size).astype(np.int32).reshape(tuple(dims))
    total = counts
    for axis in range(3):  # the 3x3x3 sum, one axis at a time (cells 0 and -1 are empty)
        moved = np.moveaxis(total, axis, 0)
        summed = moved.copy()
        summed[1:] += moved[:-1]
        summed[:-1] += moved[1:]
        total = np.moveaxis(summed, 0, axis)
    lonely = (total < MIN_NEIGHBOURS) & (counts > 0)
    if not lonely.any():
        return np.zeros(len(key), dtype=bool)
    return lonely.ravel()[key]


def _isolated_sparse(key: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """:func:`_isolated` by one sort of the points' cell keys, each occupied cell's 26
    neighbours looked up in it."""
    keys, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    keys_xyz = np.stack(np.unravel_index(keys, tuple(dims)), axis=1)
    total = np.zeros(len(keys), dtype=np.int64)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                k = _key(keys_xyz + np.array([dx, dy, dz]), dims)
                pos = np.clip(np.searchsorted(keys, k), 0, len(keys) - 1)
                total += np.where(keys[pos] == k, counts[pos], 0)
    return (total < MIN_NEIGHBOURS)[inverse.reshape(-1)]


def _key(cells: np.ndarray, dims: np.ndarray) -> np.ndarray:
    return (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]


def find_strays(xyz: np.ndarray) -> np.ndarray:
    """(N,) bool: the stray points of a levelled scan in metres: cut off from the bulk by an
    empty gap along an axis, or lonely and outside the box of the rest (where they would move
    the extent every normalisation reads)."""
    if len(xyz) < 100:
        return np.zeros(len(xyz), dtype=bool)
    return strays_of_columns(np.ascontiguousarray(xyz.T))


def work_columns(
    xyz: np.ndarray, centre: np.ndarray, rotation: np.ndarray, metres: float
) -> np.ndarray:
    """The work frame's coordinates ``((xyz - centre) @ rotation.T) * metres`` as three
    contiguous columns, (3, N). A rotation that only swaps and flips axes (every frame not
    levelled) is done column by column: its product picks one signed coordinate exactly, so
    the values are the product's without the (N, 3) temporaries."""
    r = np.asarray(rotation, dtype=np.float64)
    signed = np.abs(r)
    picks = np.argmax(signed, axis=1)
    if not (np.all(np.isin(r, (-1.0, 0.0, 1.0))) and np.all(signed.sum(axis=1) == 1.0)):
        return np.ascontiguousarray((((xyz - centre) @ r.T) * metres).T)
    out = np.empty((3, len(xyz)))
    for i, j in enumerate(picks):
        np.subtract(xyz[:, j], centre[j], out=out[i])
        np.multiply(out[i], r[i, j] * metres, out=out[i])
    return out


def strays_of_columns(columns: np.ndarray) -> np.ndarray:
    """:func:`find_strays` of the points' coordinate columns, (3, N) contiguous."""
    n = columns.shape[1]
    stray = np.zeros(n, dtype=bool)
    if n < 100:
        return stray
    for axis in range(3):
        cut = _bulk_cut(columns[axis])
        if cut is not None:
            idx, first, last = cut
            stray |= (idx <= first) | (idx >= last)
    if np.count_nonzero(stray) / n > MAX_SHARE:
        stray[:] = False
    lonely = _isolated(columns)
    count = np.count_nonzero(lonely)
    if count == 0 or count / n > MAX_SHARE:
        return stray
    rest = ~(stray | lonely)
    if rest.any():
        # a lonely point inside the box of the rest moves no normalisation: leave it be
        lo = np.min(columns, axis=1, where=rest[None, :], initial=np.inf) - BOX_TOLERANCE_M
        hi = np.max(columns, axis=1, where=rest[None, :], initial=-np.inf) + BOX_TOLERANCE_M
        idx = np.flatnonzero(lonely)
        p = columns[:, idx].T
        stray[idx[np.any((p < lo) | (p > hi), axis=1)]] = True
    return stray
