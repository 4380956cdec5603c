"""Objects from labelled points: the points of one class that touch form one object.

Contact is found on a voxel grid, not per point: every class's points are binned into cells
one contact distance wide and neighbouring occupied cells (26-neighbourhood) are joined, so the
cost is a sort of the cells, linear in the points, and an object spanning two tiles is one
object as long as its points reach across.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from jointseg.grouping import compact_ids
from jointseg.objects.params import THING_CLASSES, ObjectParams

#: The 13 forward neighbours of a cell (the other 13 are their opposites).
_OFFSETS = np.array(
    [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
     if (dx, dy, dz) > (0, 0, 0)],
    dtype=np.int64,
)  # fmt: skip


def cell_components(cells: np.ndarray) -> np.ndarray:
    """Connected component (0..C-1) of each of the given integer cells, (M, 3) -> (M,), where
    cells that touch (faces, edges or corners) are connected."""
    if len(cells) == 0:
        return np.zeros(0, dtype=np.int64)
    lo = cells.min(axis=0)
    c = cells - lo + 1
    dims = c.max(axis=0) + 2
    key = (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]
    order = np.argsort(key, kind="stable")
    sorted_keys = key[order]
    src, dst = [], []
    for off in _OFFSETS:
        other = key + (off[0] * dims[1] + off[1]) * dims[2] + off[2]
        at = np.searchsorted(sorted_keys, other)
        at = np.minimum(at, len(sorted_keys) - 1)
        hit = sorted_keys[at] == other
        src.append(np.flatnonzero(hit))
        dst.append(order[at[hit]])
    s, d = np.concatenate(src), np.concatenate(dst)
    n = len(cells)
    graph = coo_matrix((np.ones(len(s), dtype=np.int8), (s, d)), shape=(n, n)).tocsr()
    return connected_components(graph, directed=False)[1].astype(np.int64)


def find_instances(
    xyz: np.ndarray, labels: np.ndarray, spacing: float, params: ObjectParams | None = None
) -> np.ndarray:
    """An object id per point (0..K-1, ordered by class then size), -1 for structure (ceiling,
    floor, wall), unlabelled points and groups under ``params.min_points``.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), metres
    labels : ndarray of shape (N,), int
        Fused labels (S3DIS classes).
    spacing : float
        The scan's point spacing, metres: the contact distance is ``params.contact`` times it.
    """
    params = params or ObjectParams()
    out = np.full(len(xyz), -1, dtype=np.int64)
    size = max(params.contact * spacing, params.min_contact)
    next_id = 0
    for cls in THING_CLASSES:
        members = np.flatnonzero(labels == cls)
        if members.size < params.min_points:
            continue
        points = np.take(xyz, members, axis=0)
        cell = [np.floor(points[:, a] / size).astype(np.int64) for a in range(3)]
        for c in cell:  # each axis from 0 (reduced column by column: the same cells)
            c -= c.min()
        dims = np.array([c.max() + 1 for c in cell])
        key = (cell[0] * dims[1] + cell[1]) * dims[2] + cell[2]
        # the occupied cells in key order (as np.unique sorts them), each from its own key
        uniq_key, inverse = compact_ids(key)
        cells = np.stack(np.unravel_index(uniq_key, tuple(int(d) for d in dims)), axis=1)
        comp = cell_components(cells.astype(np.int64))[inverse]
        comp = _join_parts(points, comp)
        counts = np.bincount(comp)
        keep = np.flatnonzero(counts >= params.min_points)
        keep = keep[np.argsort(-counts[keep], kind="stable")]
        new = np.full(counts.size, -1, dtype=np.int64)
        new[keep] = np.arange(next_id, next_id + keep.size)
        out[members] = new[comp]
        next_id += keep.size
    return out


#: A part joins a larger object of its class when it is this much smaller at most ...
PART_SHARE = 0.2
#: ... and its footprint lies within the larger one's, grown by this margin (m).
PART_MARGIN = 0.1


def _join_parts(xyz: np.ndarray, comp: np.ndarray) -> np.ndarray:
    """Pieces of one object the scan cut apart: a table leg whose top is hidden under the
    table top, a chair leg below its seat. A small group lying inside a larger group's
    footprint (seen from above) joins it."""
    n = int(comp.max()) + 1 if comp.size else 0
    if n < 2:
        return comp
    counts = np.bincount(comp, minlength=n)
    order = group_order(comp, n)
    starts = np.r_[0, np.cumsum(counts)[:-1]]  # every group 0..n-1 has points
    xy = np.take(xyz, order, axis=0)[:, :2]
    lo = np.minimum.reduceat(xy, starts, axis=0)
    hi = np.maximum.reduceat(xy, starts, axis=0)
    target = part_targets(counts, lo, hi)
    # follow chains (a part of a part) to their root
    for _ in range(4):
        target = target[target]
    return target[comp]


def group_order(ids: np.ndarray, n: int) -> np.ndarray:
    """The rows ordered by id (0..n-1), each id's rows ascending: a stable sort, on 16-bit
    keys where the ids fit them (numpy sorts those by radix, in linear time)."""
    if n <= np.iinfo(np.int16).max:
        return np.argsort(ids.astype(np.int16), kind="stable")
    return np.argsort(ids, kind="stable")


def rows_by_group(ids: np.ndarray) -> list[np.ndarray]:
    """:func:`jointseg.grouping.rows_by_id` (the rows of each id >= 0, ascending, ids in
    ascending order) through :func:`group_order`."""
    valid = np.flatnonzero(ids >= 0)
    if valid.size == 0:
        return []
    order = valid[group_order(ids[valid], int(ids[valid].max()) + 1)]
    bounds = np.flatnonzero(np.diff(ids[order])) + 1
    return np.split(order, bounds)


#: Parts and objects compared at once in :func:`part_targets` (pairs), to bound its memory.
PAIRS_PER_BLOCK = 1 << 22


def part_targets(counts: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """For each group (``counts`` points, plan box ``lo``..``hi``, (n, 2)), the group it joins:
    the largest (the first of equals) of those at least ``1 / PART_SHARE`` times its size
    whose box, grown by ``PART_MARGIN``, holds its own; itself when none does. Every pair is
    compared at once, a block of parts at a time."""
    n = len(counts)
    target = np.arange(n)
    big = np.flatnonzero(counts * PART_SHARE >= counts.min())  # any group is part of these
    if big.size == 0:
        return target
    small = np.flatnonzero(counts <= counts[big].max() * PART_SHARE)
    grown_lo, grown_hi = lo[big] - PART_MARGIN, hi[big] + PART_MARGIN
    size = counts[big]
    step = max(1, PAIRS_PER_BLOCK // big.size)
    for first in range(0, small.size, step):
        rows = small[first : first + step]
        holds = (
            (size[None, :] * PART_SHARE >= counts[rows, None])
            & np.all(grown_lo[None, :, :] <= lo[rows, None, :], axis=2)
            & np.all(grown_hi[None, :, :] >= hi[rows, None, :], axis=2)
        )
        found = holds.any(axis=1)
        best = np.argmax(np.where(holds, size[None, :], -1), axis=1)
        target[rows[found]] = big[best[found]]
    return target
