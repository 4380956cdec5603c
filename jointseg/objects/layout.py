"""From labels to a building: objects, rooms, walls with their doors and windows.

:func:`find_layout` runs in the frame stage's levelled metric frame (z up, metres) on the fused
labels, and reports every position in the user's own coordinates through ``to_user``. The
records are pydantic models, so the report, ``objects.json`` and the IFC writer read one shape.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.geometry.alignment import dominant_yaw, point_normals
from jointseg.grouping import rows_by_id
from jointseg.objects.instances import find_instances
from jointseg.objects.params import DOOR, FLOOR, WALL, WINDOW, ObjectParams
from jointseg.objects.records import (
    LayoutReport,
    ObjectRecord,
    OpeningRecord,
    RoomRecord,
    Vec,
    WallRecord,
)
from jointseg.objects.rooms import RoomGrid, ceiling_heights, floor_height, room_areas, room_grid

log = logging.getLogger(__name__)

#: A wall plane is cut where its points (and its doors and windows) leave a gap this wide, m:
#: furniture in front of a wall hides stretches of it shorter than that.
WALL_GAP = 2.0


@dataclass(frozen=True)
class Layout:
    """Per-point object ids and the report."""

    instances: np.ndarray
    report: LayoutReport


def find_layout(
    xyz: np.ndarray,
    labels: np.ndarray,
    confidence: np.ndarray | None,
    spacing: float,
    to_user: np.ndarray | None = None,
    params: ObjectParams | None = None,
) -> Layout:
    """Objects, rooms and walls of a labelled scan.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
        Levelled metric points (the frame stage's work frame).
    labels : ndarray of shape (N,), int
        Fused labels.
    confidence : ndarray of shape (N,), optional
        Fused confidence per point.
    spacing : float
        Point spacing, metres.
    to_user : ndarray of shape (4, 4), optional
        Work -> user coordinates (identity when None).
    """
    params = params or ObjectParams()
    matrix = np.eye(4) if to_user is None else np.asarray(to_user, dtype=np.float64)
    instances = find_instances(xyz, labels, spacing, params)
    floor_z = floor_height(xyz[:, 2], labels)
    walls_mask = labels == WALL
    # normals of the wall and door points only: the walls' direction, planes and the rooms'
    # barriers need no others
    barrier = walls_mask | (labels == DOOR)
    barrier_normals = point_normals(xyz[barrier], spacing) if walls_mask.sum() >= 10 else None
    normals = None if barrier_normals is None else barrier_normals[walls_mask[barrier]]
    yaw = dominant_yaw(normals) if normals is not None else 0.0
    report = LayoutReport(floor_z=floor_z, yaw=yaw, to_user=matrix.tolist())
    conf = np.ones(len(xyz)) if confidence is None else np.asarray(confidence, np.float64)
    if floor_z is None:
        report.reason = "no floor found (fewer than 50 floor points): no rooms, no heights"
        report.objects = _objects(xyz, labels, conf, instances, matrix, yaw, None, None)
        return Layout(instances, report)
    grid = room_grid(xyz, labels, yaw, floor_z, params, barrier_normals)
    report.objects = _objects(xyz, labels, conf, instances, matrix, yaw, floor_z, grid)
    if grid.labels.size == 0 or grid.labels.max() < 0:
        report.reason = "no room found: the floor is not closed by walls into any region"
        return Layout(instances, report)
    report.rooms = _rooms(xyz, labels, grid, floor_z)
    report.walls, places = _walls(
        xyz, labels, normals, instances, report, grid, floor_z, params, matrix, spacing
    )
    _fit_to_walls(report.rooms, grid, places)
    for obj in report.objects:
        if obj.room is not None and obj.room < len(report.rooms):
            report.rooms[obj.room].objects.append(obj.id)
    if not report.walls:
        report.reason = "no wall plane long enough was found"
    return Layout(instances, report)


def _apply(matrix: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    return np.asarray(xyz, dtype=np.float64) @ matrix[:3, :3].T + matrix[:3, 3]


def _vec(v: np.ndarray) -> Vec:
    return (float(v[0]), float(v[1]), float(v[2]))


def _objects(
    xyz: np.ndarray,
    labels: np.ndarray,
    conf: np.ndarray,
    instances: np.ndarray,
    matrix: np.ndarray,
    yaw: float,
    floor_z: float | None,
    grid: RoomGrid | None,
) -> list[ObjectRecord]:
    groups = rows_by_id(instances)
    if not groups:
        return []
    helper = grid or RoomGrid(np.zeros((0, 0), np.int64), np.zeros(2), 1.0, yaw)
    out = []
    for rows in groups:
        p = xyz[rows]
        plan = helper.plan_xy(p)
        lo = np.r_[plan.min(axis=0), p[:, 2].min()]
        hi = np.r_[plan.max(axis=0), p[:, 2].max()]
        corners_plan = np.array(
            [[x, y, z] for z in (lo[2], hi[2]) for x, y in
             ((lo[0], lo[1]), (hi[0], lo[1]), (hi[0], hi[1]), (lo[0], hi[1]))]
        )  # fmt: skip
        corners = np.c_[helper.work_xy(corners_plan[:, :2]), corners_plan[:, 2]]
        cls = int(np.bincount(labels[rows], minlength=NUM_CLASSES).argmax())
        centroid = p.mean(axis=0)
        room = None
        if grid is not None and grid.labels.size:
            r = int(grid.room_of(centroid[None])[0])
            room = r if r >= 0 else None
        out.append(
            ObjectRecord(
                id=int(instances[rows[0]]),
                cls=CLASS_NAMES[cls],
                points=int(rows.size),
                confidence=round(float(conf[rows].mean()), 4),
                centroid=_vec(_apply(matrix, centroid)),
                box=[_vec(c) for c in _apply(matrix, corners)],
                size=_vec(hi - lo),
                height_above_floor=round(float(lo[2] - (floor_z or 0.0)), 4),
                room=room,
            )
        )
    return out


def _rooms(xyz: np.ndarray, labels: np.ndarray, grid: RoomGrid, floor_z: float) -> list[RoomRecord]:
    areas = room_areas(grid)
    room = grid.room_of(xyz)
    heights = ceiling_heights(xyz, labels, room, floor_z, len(areas))
    out = []
    for r, area in enumerate(areas):
        ii, jj = np.nonzero(grid.labels == r)
        extent = np.array([np.ptp(ii) + 1, np.ptp(jj) + 1]) * grid.cell
        long, short = max(extent), max(min(extent), 1e-6)
        kind = "corridor" if long / short > 3.0 and short < 3.0 else "room"
        outline = room_outline(grid.labels == r) * grid.cell + grid.origin
        height = None if np.isnan(heights[r]) else round(float(heights[r]), 4)
        out.append(
            RoomRecord(
                id=r,
                name=f"{'Corridor' if kind == 'corridor' else 'Room'} {r + 1}",
                kind=kind,
                floor_area=round(float(area), 3),
                ceiling_height=height,
                footprint=[(float(x), float(y)) for x, y in grid.work_xy(outline)],
            )
        )
    return out


def room_outline(mask: np.ndarray) -> np.ndarray:
    """The outline of a room's cells, (K, 2) in cell units (row, column), as one polygon: the
    union of each row's runs of cells, its largest part, simplified within half a cell."""
    from shapely.geometry import box
    from shapely.ops import unary_union

    rects = []
    for i in np.flatnonzero(mask.any(axis=1)):
        row = np.r_[False, mask[i], False].astype(np.int8)
        edges = np.flatnonzero(np.diff(row))
        rects += [box(i, a, i + 1, b) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    shape = unary_union(rects)
    if shape.geom_type == "MultiPolygon":
        shape = max(shape.geoms, key=lambda g: g.area)
    ring = np.asarray(shape.simplify(0.5).exterior.coords)[:-1]
    return ring.astype(np.float64)


def _walls(
    xyz: np.ndarray,
    labels: np.ndarray,
    normals: np.ndarray | None,
    instances: np.ndarray,
    report: LayoutReport,
    grid: RoomGrid,
    floor_z: float,
    params: ObjectParams,
    matrix: np.ndarray,
    spacing: float,
) -> tuple[list[WallRecord], list[_Place]]:
    """Wall planes along the plan's two axes, cut where the wall (or a door or window in it)
    has a gap, each with the rooms beside it and the doors and windows in it."""
    if normals is None:
        return [], []
    wall = np.flatnonzero(labels == WALL)
    plan = grid.plan_xy(xyz[wall])
    n_plan = grid.plan_xy(normals)  # the wall points' normals
    openings = np.flatnonzero(((labels == DOOR) | (labels == WINDOW)) & (instances >= 0))
    open_plan = grid.plan_xy(xyz[openings])
    floor_plan = grid.plan_xy(xyz[labels == FLOOR])
    top = float(np.quantile(xyz[wall, 2], 0.99)) if wall.size else floor_z
    out: list[WallRecord] = []
    places: list[_Place] = []
    wall_z = xyz[wall, 2]
    for axis in (0, 1):
        facing = np.abs(n_plan[:, axis]) > 0.8
        coord = plan[facing, axis]
        along = plan[facing, 1 - axis]
        for c in _planes(coord, min_count=max(50, int(0.002 * wall.size))):
            on = np.abs(coord - c) < 0.06
            near_open = np.abs(open_plan[:, axis] - c) < 0.3
            u = np.sort(np.r_[along[on], open_plan[near_open, 1 - axis]])
            for u0, u1 in _runs(u, gap=WALL_GAP):
                if u1 - u0 < params.min_wall_length:
                    continue
                out.append(_wall(len(out), axis, c, u0, u1, floor_z, top, grid, matrix))
                back = _back_side(floor_plan, axis, c, u0, u1)
                places.append(_Place(axis, c, u0, u1, back, along[on], wall_z[facing][on]))
    objects = {o.id: o for o in report.objects}
    by_id = _groups(instances, openings)
    open_normals = np.zeros((len(xyz), 2))
    if openings.size:
        open_normals[openings] = grid.plan_xy(point_normals(xyz[openings], spacing))
    for w, place in zip(out, places, strict=True):
        _add_openings(w, place, by_id, objects, xyz, open_normals, grid, floor_z)
    for r in report.rooms:
        r.walls = [w.id for w in out if r.id in w.rooms]
    return out, places


def _fit_to_walls(rooms: list[RoomRecord], grid: RoomGrid, places: list[_Place]) -> None:
    """Move each straight edge of a room's outline onto the wall face it runs along (within
    0.15 m), and measure the area of that outline: the grid's cells straddle the faces, and
    furniture against a wall hides the floor's last few centimetres before it."""
    for room in rooms:
        ring = _cell_ring(grid.labels == room.id)
        if ring is None:
            continue
        plan = ring * grid.cell + grid.origin
        fitted = _snap_ring(plan, places)
        area = _ring_area(fitted)
        if not 0.9 * room.floor_area < area < 1.1 * room.floor_area:
            continue  # a tangled or far-moved outline: keep the grid's own
        room.floor_area = round(area, 3)
        room.footprint = [(float(x), float(y)) for x, y in grid.work_xy(fitted)]


def _cell_ring(mask: np.ndarray) -> np.ndarray | None:
    """The room's cells' outline (cell units), axis-aligned, no collinear corners."""
    from shapely.geometry import Polygon, box
    from shapely.ops import unary_union

    rects = []
    for i in np.flatnonzero(mask.any(axis=1)):
        row = np.r_[False, mask[i], False].astype(np.int8)
        edges = np.flatnonzero(np.diff(row))
        rects += [box(i, a, i + 1, b) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    if not rects:
        return None
    shape = unary_union(rects)
    if shape.geom_type == "MultiPolygon":
        shape = max(shape.geoms, key=lambda g: g.area)
    ring = np.asarray(Polygon(shape.exterior).simplify(0.0).exterior.coords)[:-1]
    return ring.astype(np.float64) if len(ring) >= 4 else None


def _snap_ring(ring: np.ndarray, places: list[_Place]) -> np.ndarray:
    """Each edge of an axis-aligned ring (plan metres) at least 0.3 m long moved onto the
    nearest wall face along it within 0.15 m; each corner takes its two edges' positions."""
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
        if hi - lo < 0.3:
            continue
        # the face of this room's side: its wall's body lies outward of the room
        near = [
            p.c
            for p in places
            if p.axis == a
            and p.back == outward[k, a]
            and abs(p.c - ring[k, a]) < 0.2
            and p.u0 < hi
            and p.u1 > lo
        ]
        if near:
            value[k] = min(near, key=lambda c: abs(c - ring[k, a]))
    out = ring.copy()
    for k in range(n):  # a corner k lies on edge k and on edge k - 1
        for e in (k, k - 1):
            out[k, const[e]] = value[e]
    return out


def _signed_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) / 2


def _ring_area(ring: np.ndarray) -> float:
    return abs(_signed_area(ring))


@dataclass(frozen=True)
class _Place:
    """A wall face in the plan: its axis, offset and span, the side of the face its wall's body
    lies on (+1 or -1 along ``axis``), and its own points (along it, height)."""

    axis: int
    c: float
    u0: float
    u1: float
    back: int
    u: np.ndarray
    z: np.ndarray


def _back_side(floor_plan: np.ndarray, axis: int, c: float, u0: float, u1: float) -> int:
    """Which side of a wall face is the wall's body: the side with no floor in the first few
    centimetres (a room's floor runs up to the face, and any wall is thicker than 8 cm)."""
    along = floor_plan[:, 1 - axis]
    off = floor_plan[:, axis] - c
    beside = (along > u0) & (along < u1)
    plus = int(np.count_nonzero(beside & (off > 0.02) & (off < 0.08)))
    minus = int(np.count_nonzero(beside & (off < -0.02) & (off > -0.08)))
    return 1 if plus < minus else -1


def _planes(coord: np.ndarray, *, min_count: int, bin_width: float = 0.05) -> list[float]:
    """Offsets where many points share one coordinate: histogram peaks, refined by a mean."""
    if coord.size < min_count:
        return []
    lo = coord.min()
    bins = np.floor((coord - lo) / bin_width).astype(np.int64)
    hist = np.bincount(bins)
    out = []
    for b in np.flatnonzero(hist >= min_count):
        if b > 0 and hist[b - 1] > hist[b] or b + 1 < hist.size and hist[b + 1] > hist[b]:
            continue
        near = np.abs(coord - (lo + (b + 0.5) * bin_width)) < 1.5 * bin_width
        out.append(float(coord[near].mean()))
    return out


def _runs(u: np.ndarray, *, gap: float) -> list[tuple[float, float]]:
    if u.size == 0:
        return []
    cuts = np.flatnonzero(np.diff(u) > gap)
    starts = np.r_[0, cuts + 1]
    ends = np.r_[cuts, u.size - 1]
    return [(float(u[a]), float(u[b])) for a, b in zip(starts, ends, strict=True)]


def _wall(
    index: int,
    axis: int,
    c: float,
    u0: float,
    u1: float,
    floor_z: float,
    top: float,
    grid: RoomGrid,
    matrix: np.ndarray,
) -> WallRecord:
    def point(u: float) -> np.ndarray:
        p = np.zeros(2)
        p[axis], p[1 - axis] = c, u
        return p

    ends = np.array([point(u0), point(u1)])
    work = grid.work_xy(ends)
    corners = np.array([[*work[0], floor_z], [*work[1], floor_z], [*work[1], top], [*work[0], top]])
    # rooms on either side: probe the grid 0.25 m off the wall's middle
    mid = point((u0 + u1) / 2)
    probes = []
    for side in (-0.25, 0.25):
        q = mid.copy()
        q[axis] += side
        probes.append(q)
    beside = grid.room_of(np.c_[grid.work_xy(np.array(probes)), np.zeros(2)])
    length, height = u1 - u0, top - floor_z
    return WallRecord(
        id=index,
        corners=[_vec(v) for v in _apply(matrix, corners)],
        length=round(length, 3),
        height=round(height, 3),
        area=round(length * height, 3),
        net_area=round(length * height, 3),
        rooms=sorted({int(r) for r in beside if r >= 0}),
    )


def _groups(instances: np.ndarray, rows: np.ndarray) -> dict[int, np.ndarray]:
    """The given rows by object id."""
    return {int(instances[rows[part[0]]]): rows[part] for part in rows_by_id(instances[rows])}


def _add_openings(
    wall: WallRecord,
    place: _Place,
    rows_of: dict[int, np.ndarray],
    objects: dict[int, ObjectRecord],
    xyz: np.ndarray,
    normals: np.ndarray,
    grid: RoomGrid,
    floor_z: float,
) -> None:
    """Doors and windows lying in the wall's plane (within 0.3 m) and span. Their width is the
    gap they leave in the wall's own points at their height (an open door's leaf sticks out of
    the wall, so its points' extent is not the opening), else their points' extent; a door's
    trims standing proud of its leaf on either side are taken off (:func:`_inside_trims`)."""
    axis = place.axis
    for obj_id, rows in rows_of.items():
        obj = objects.get(obj_id)
        if obj is None or obj.cls not in ("door", "window"):
            continue
        plan = grid.plan_xy(xyz[rows])
        if abs(float(np.median(plan[:, axis])) - place.c) > 0.3:
            continue
        u = plan[:, 1 - axis]
        mid = float(np.median(u))
        if not place.u0 - 0.2 <= mid <= place.u1 + 0.2:
            continue
        zlo, zhi = (float(v) for v in np.quantile(xyz[rows, 2], [0.01, 0.99]))
        lo, hi = (float(v) for v in np.quantile(u, [0.01, 0.99]))
        band = (place.z > zlo + 0.25 * (zhi - zlo)) & (place.z < zhi - 0.25 * (zhi - zlo))
        left, right = place.u[band & (place.u < mid)], place.u[band & (place.u > mid)]
        gap = (float(left.max()), float(right.min())) if left.size and right.size else (lo, hi)
        # trims hide the wall up to the opening's outer edges: a wider gap is missing wall
        if 0.3 < gap[1] - gap[0] < 3.0 and gap[0] >= lo - 0.05 and gap[1] <= hi + 0.05:
            lo, hi = gap
        if obj.cls == "door":
            z = xyz[rows, 2]
            facing = (np.abs(normals[rows, axis]) > 0.8) & (z > zlo + 0.3 * (zhi - zlo))
            facing &= z < zhi - 0.3 * (zhi - zlo)
            lo, hi = _inside_trims(u[facing], plan[facing, axis], lo, hi)
        opening = OpeningRecord(
            object=obj_id,
            kind=obj.cls,
            width=round(hi - lo, 3),
            height=round(zhi - zlo, 3),
            sill=round(zlo - floor_z, 3),
        )
        wall.openings.append(opening)
        wall.net_area = round(max(wall.net_area - opening.width * opening.height, 0.0), 3)


def _inside_trims(u: np.ndarray, depth: np.ndarray, lo: float, hi: float) -> tuple[float, float]:
    """The opening between a door's or window's trims (casings, architraves).

    Across the opening (2 cm bins along the wall, the median depth of the surfaces facing
    the room) a trim is a run at each end whose depth differs by 1.5 cm or more from the leaf
    or glass between: the opening begins where that run ends. An end without such a run keeps
    its measured edge.
    """
    step = 0.02
    bins = np.floor((u - lo) / step).astype(np.int64)
    keep = (bins >= 0) & (bins < max(int(np.ceil((hi - lo) / step)), 1))
    bins, depth = bins[keep], depth[keep]
    n = int(np.ceil((hi - lo) / step))
    if n < 12 or bins.size == 0:
        return lo, hi
    order = np.argsort(bins, kind="stable")
    bins, depth = bins[order], depth[order]
    starts = np.searchsorted(bins, np.arange(n))
    ends = np.searchsorted(bins, np.arange(n), side="right")
    profile = np.full(n, np.nan)
    for b in np.flatnonzero(ends - starts >= 3):  # n bins (tens), not points
        profile[b] = np.median(depth[starts[b] : ends[b]])
    seen = np.flatnonzero(~np.isnan(profile))
    if seen.size < 8:
        return lo, hi
    middle = float(np.median(profile[seen[seen.size // 4 : 3 * seen.size // 4]]))
    new_lo, new_hi = lo, hi
    for side, run in ((0, seen[:4]), (1, seen[::-1][:4])):
        trim = float(np.median(profile[run[:2]]))
        if abs(trim - middle) < 0.015:
            continue
        walk = seen if side == 0 else seen[::-1]
        last = None
        for b in walk:
            if abs(profile[b] - trim) >= 0.01:
                break
            last = b
        if last is None:
            continue
        if side == 0:
            new_lo = lo + (last + 1) * step
        else:
            new_hi = lo + last * step
    if new_hi - new_lo < 0.3:
        return lo, hi
    return new_lo, new_hi
