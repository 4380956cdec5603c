"""Stray points: returns through windows and off mirrors, metres outside the room.

A handful of them moves every normalisation that looks at extremes (the network's height above
the lowest point, the geometry's bounding-box faces). Two rules, in the levelled metric frame:
points separated from the scan's bulk along an axis by an empty gap, and points with almost no
neighbours. Both are cheap: a histogram per axis and a voxel hash.
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


def bulk_mask(values: np.ndarray) -> np.ndarray:
    """Points within the stretch of ``values`` that holds the median, where no gap of
    :data:`GAP_M` without a share of the points interrupts it."""
    lo, hi = float(values.min()), float(values.max())
    if hi - lo <= GAP_M:
        return np.ones(len(values), dtype=bool)
    bins = int(np.ceil((hi - lo) / BIN_M)) + 1
    idx = ((values - lo) / BIN_M).astype(np.int64)
    counts = np.bincount(idx, minlength=bins)
    # a bin holding a few scattered strays is as good as empty: it takes a share of the scan
    occupied = counts >= max(2.0, OCCUPIED_SHARE * len(values))
    start = stop = int((np.median(values) - lo) / BIN_M)
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
    return (idx > start - gap) & (idx < stop + gap)


def isolated_mask(xyz: np.ndarray) -> np.ndarray:
    """Points with fewer than :data:`MIN_NEIGHBOURS` points in their 27 surrounding cells
    (one sort of the points' cell keys; each occupied cell's 26 neighbours looked up in it)."""
    cells = np.floor((xyz - xyz.min(axis=0)) / CELL_M).astype(np.int64) + 1
    dims = cells.max(axis=0) + 2
    keys, inverse, counts = np.unique(_key(cells, dims), return_inverse=True, return_counts=True)
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
    stray = np.zeros(len(xyz), dtype=bool)
    if len(xyz) < 100:
        return stray
    columns = np.ascontiguousarray(xyz.T)  # the axes' values, each read several times
    for axis in range(3):
        stray |= ~bulk_mask(columns[axis])
    if stray.mean() > MAX_SHARE:
        stray[:] = False
    lonely = isolated_mask(xyz)
    rest = ~(stray | lonely)
    if lonely.mean() <= MAX_SHARE and rest.any():
        # a lonely point inside the box of the rest moves no normalisation: leave it be
        lo = np.min(columns, axis=1, where=rest, initial=np.inf) - BOX_TOLERANCE_M
        hi = np.max(columns, axis=1, where=rest, initial=-np.inf) + BOX_TOLERANCE_M
        idx = np.flatnonzero(lonely)
        stray[idx[np.any((xyz[idx] < lo) | (xyz[idx] > hi), axis=1)]] = True
    return stray
