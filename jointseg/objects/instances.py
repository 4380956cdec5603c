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
        cell = np.floor(xyz[members] / size).astype(np.int64)
        cell -= cell.min(axis=0)
        dims = cell.max(axis=0) + 1
        key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        uniq_key, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        comp = cell_components(cell[first])[inverse.reshape(-1)]
        comp = _join_parts(xyz[members], comp)
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
    lo = np.full((n, 2), np.inf)
    hi = np.full((n, 2), -np.inf)
    np.minimum.at(lo, comp, xyz[:, :2])
    np.maximum.at(hi, comp, xyz[:, :2])
    target = np.arange(n)
    for small in np.argsort(counts, kind="stable"):
        big = np.flatnonzero(
            (counts * PART_SHARE >= counts[small])
            & np.all(lo - PART_MARGIN <= lo[small], axis=1)
            & np.all(hi + PART_MARGIN >= hi[small], axis=1)
        )
        if big.size:
            target[small] = big[np.argmax(counts[big])]
    # follow chains (a part of a part) to their root
    for _ in range(4):
        target = target[target]
    return target[comp]
