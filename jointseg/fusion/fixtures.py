"""Which of the network's wall fixtures are believable (issue 43).

The vote keeps a window, door or board that lies in a wall's plane where the network sees it:
the structure reading cannot tell them from the wall. On scans from other sensors, though, the
network calls whole stretches of wall "door". A door has a size: at most a double door with
its frame wide, and a door leaf is tall. A door stands on the floor, too. A "door" of the
network's that is much wider, wide and low, lower than any door seen even in part, or that
floats above the floor (where the geometry found one), is a wall it mistook, and the vote need
not protect it.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from jointseg.classes import CLASS_INDEX
from jointseg.grouping import compact_ids, group_quantiles

DOOR, COLUMN = CLASS_INDEX["door"], CLASS_INDEX["column"]
#: Side (m) of the cells that join door points into one door.
CELL = 0.1
#: A door is at most this wide (m): a double door with its frame (S3DIS's widest, seen open,
#: span 2.1 m).
MAX_WIDTH = 2.4
#: A door wider than LOW_WIDTH (m) is at least LOW_HEIGHT (m) high.
LOW_WIDTH, LOW_HEIGHT = 1.4, 1.5
#: Any door is at least this high (m), even seen in part (an RGB-D sweep may miss its top).
MIN_HEIGHT = 1.0
#: A door's bottom lies at most this far (m) above the floor level: a door leaf stands on the
#: floor (S3DIS's doors start within 0.1 m of it, ScanNet's within 0.35 m).
MAX_FOOT = 0.4
#: Fewer door points than this are left alone (too few to measure).
MIN_POINTS = 100
#: A column (or a pilaster standing out of a wall) is at most this wide (m): S3DIS's, as the
#: network finds them on the tuning rooms, span 0.7 to 1.05 m; a wider "column" is a wall.
MAX_COLUMN_WIDTH = 1.2


def implausible_doors(
    xyz: np.ndarray, labels: np.ndarray, floor_z: float | None = None
) -> np.ndarray:
    """Points the network labelled door in doors of no believable size or place (bool, N); the
    scan is levelled (z up, metres). Doors are the door points' connected CELL cells; a door's
    width is its extent along its main horizontal direction. ``floor_z``: the floor level, where
    known (the structure reading's); a door whose bottom is over MAX_FOOT above it floats."""
    out = np.zeros(len(labels), dtype=bool)
    found = _measured(xyz, labels, DOOR)
    if found is None:
        return out
    idx, door, (width, height, bottom, count) = found
    bad = (count >= MIN_POINTS) & (
        (width > MAX_WIDTH) | ((width > LOW_WIDTH) & (height < LOW_HEIGHT)) | (height < MIN_HEIGHT)
    )
    if floor_z is not None:
        bad |= (count >= MIN_POINTS) & (bottom > floor_z + MAX_FOOT)
    out[idx[bad[door]]] = True
    return out


def implausible_columns(xyz: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Points the network labelled column in "columns" wider than any column
    (:data:`MAX_COLUMN_WIDTH`; bool, N): on other sensors the network calls stretches of wall
    column, and the vote need not keep them. Columns are joined as doors are."""
    out = np.zeros(len(labels), dtype=bool)
    found = _measured(xyz, labels, COLUMN)
    if found is None:
        return out
    idx, column, (width, _, _, count) = found
    bad = (count >= MIN_POINTS) & (width > MAX_COLUMN_WIDTH)
    out[idx[bad[column]]] = True
    return out


def _measured(
    xyz: np.ndarray, labels: np.ndarray, cls: int
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]] | None:
    """The points labelled ``cls`` (their indices), the connected piece each belongs to and
    each piece's :func:`_extents`; None with fewer than MIN_POINTS such points."""
    idx = np.flatnonzero(np.asarray(labels) == cls)
    if len(idx) < MIN_POINTS:
        return None
    points = np.take(np.asarray(xyz, dtype=np.float64), idx, axis=0)
    piece, n = _pieces(points)
    return idx, piece, _extents(points, piece, n)


def _pieces(xyz: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected pieces of points: their occupied CELL cells, joined where they touch."""
    flat, dims = _cell_keys(np.asarray(xyz, dtype=np.float64))
    # the cells in their lexicographic order (np.unique(cells, axis=0)'s)
    flat, cell_of = compact_ids(flat)
    keys = np.column_stack(np.unravel_index(flat, dims))
    pairs = cKDTree(keys).query_pairs(np.sqrt(3) + 1e-6, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), (len(keys),) * 2)
    n, piece_of_cell = connected_components(graph, directed=False)
    return piece_of_cell[cell_of], int(n)


def _cell_keys(xyz: np.ndarray) -> tuple[np.ndarray, tuple[int, ...]]:
    """Each point's CELL cell as one row-major integer over the points' bounding box of cells,
    and that box's size in cells; one coordinate at a time."""
    keys = np.zeros(len(xyz), dtype=np.int64)
    dims = []
    for axis in range(xyz.shape[1]):
        cells = np.floor(xyz[:, axis] / CELL).astype(np.int64)
        cells -= cells.min()
        dims.append(int(cells.max()) + 1)
        keys *= dims[-1]
        keys += cells
    return keys, tuple(dims)


def _extents(xyz: np.ndarray, group: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    """Per group: extent along its main horizontal direction, height (2nd to 98th percentile
    of z), bottom (2nd percentile), point count."""
    count = np.bincount(group, minlength=n).astype(np.float64)
    safe = np.maximum(count, 1)
    mean = np.column_stack([np.bincount(group, xyz[:, i], n) / safe for i in range(2)])
    d = xyz[:, :2] - np.take(mean, group, axis=0)
    cov = np.empty((n, 2, 2))
    for i in range(2):
        for j in range(i, 2):
            cov[:, i, j] = cov[:, j, i] = np.bincount(group, d[:, i] * d[:, j], n) / safe
    _, vectors = np.linalg.eigh(cov)
    along = np.einsum("ni,ni->n", d, np.take(vectors[:, :, 1], group, axis=0))
    lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(lo, group, along)
    np.maximum.at(hi, group, along)
    zlo, zhi = group_quantiles(group, n, xyz[:, 2], (0.02, 0.98))
    return hi - lo, zhi - zlo, zlo, count
