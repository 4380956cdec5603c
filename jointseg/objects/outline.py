"""A room's outline in the floor plan: its grid cells' outline, each straight edge moved onto
the wall face it runs along, and the area inside.

The grid's cells straddle the faces, and furniture against a wall hides the floor's last few
centimetres before it; the faces themselves are planes measured to millimetres.
"""

from __future__ import annotations

import numpy as np

from jointseg.objects.records import RoomRecord
from jointseg.objects.rooms import RoomGrid
from jointseg.objects.walls import WallFace

#: An outline's edge moves onto a face at most this far away, m.
SNAP = 0.2
#: Shorter edges (furniture notches, steps of the grid) stay where they are, m.
MIN_EDGE = 0.3


def room_outline(mask: np.ndarray) -> np.ndarray:
    """The outline of a room's cells, (K, 2) in cell units (row, column), as one polygon: the
    union of each row's runs of cells, its largest part, simplified within half a cell."""
    ring = _cell_ring(mask, simplify=0.5)
    return np.zeros((0, 2)) if ring is None else ring


def fit_to_walls(rooms: list[RoomRecord], grid: RoomGrid, faces: list[WallFace]) -> None:
    """Each room's footprint and floor area from its outline fitted to the wall faces (kept
    from the grid where the fitted outline's area differs by 10 % or more: a tangle)."""
    for room in rooms:
        ring = _cell_ring(grid.labels == room.id, simplify=0.0)
        if ring is None:
            continue
        fitted = snap_ring(ring * grid.cell + grid.origin, faces)
        area = abs(_signed_area(fitted))
        if not 0.9 * room.floor_area < area < 1.1 * room.floor_area:
            continue
        room.floor_area = round(area, 3)
        room.footprint = [(float(x), float(y)) for x, y in grid.work_xy(fitted)]


def snap_ring(ring: np.ndarray, faces: list[WallFace]) -> np.ndarray:
    """Each edge of an axis-aligned ring (plan metres) at least ``MIN_EDGE`` long moved onto
    the nearest face along it within ``SNAP`` whose wall's body lies outside the ring; each
    corner takes its two edges' positions."""
    n = len(ring)
    ends = np.roll(ring, -1, axis=0)
    value = np.full(n, np.nan)  # per edge: its constant coordinate after the move
    const = np.where(np.abs(ends[:, 0] - ring[:, 0]) < 1e-9, 0, 1)  # axis held by the edge
    turn = 1.0 if _signed_area(ring) > 0 else -1.0  # counter-clockwise: outward is (dy, -dx)
    step = ends - ring
    outward = np.sign(turn * np.c_[step[:, 1], -step[:, 0]])
    for k in range(n):  # edges of one outline (tens), not points
        a = int(const[k])
        lo, hi = sorted((ring[k, 1 - a], ends[k, 1 - a]))
        value[k] = ring[k, a]
        if hi - lo < MIN_EDGE:
            continue
        near = [
            f.c
            for f in faces
            if f.axis == a
            and f.back == outward[k, a]
            and abs(f.c - ring[k, a]) < SNAP
            and f.u0 < hi
            and f.u1 > lo
        ]
        if near:
            value[k] = min(near, key=lambda c: abs(c - ring[k, a]))
    out = ring.copy()
    for k in range(n):  # a corner k lies on edge k and on edge k - 1
        for e in (k, k - 1):
            out[k, const[e]] = value[e]
    return out


def _cell_ring(mask: np.ndarray, *, simplify: float) -> np.ndarray | None:
    """The outline of the largest part of the cells (cell units), simplified within
    ``simplify`` cells (0: only collinear corners go, the edges stay axis-aligned)."""
    import shapely
    from shapely.geometry import Polygon
    from shapely.ops import unary_union

    # each row's runs of cells, in row order and along each row: where a run starts and ends
    steps = np.diff(np.pad(mask, ((0, 0), (1, 1))).astype(np.int8), axis=1)
    row, first = np.nonzero(steps == 1)
    _, last = np.nonzero(steps == -1)
    if row.size == 0:
        return None
    # the same boxes as shapely.geometry.box(row, first, row + 1, last), made all at once
    rects = shapely.box(row, first, row + 1, last)
    shape = unary_union(rects)
    if shape.geom_type == "MultiPolygon":
        shape = max(shape.geoms, key=lambda g: g.area)
    ring = np.asarray(Polygon(shape.exterior).simplify(simplify).exterior.coords)[:-1]
    return ring.astype(np.float64) if len(ring) >= 3 else None


def _signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2
