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
from jointseg.objects.params import DOOR, WALL, WINDOW, ObjectParams
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
    # normals of the wall points only: the walls' direction and planes need no others
    normals = point_normals(xyz[walls_mask], spacing) if walls_mask.sum() >= 10 else None
    yaw = dominant_yaw(normals) if normals is not None else 0.0
    report = LayoutReport(floor_z=floor_z, yaw=yaw, to_user=matrix.tolist())
    conf = np.ones(len(xyz)) if confidence is None else np.asarray(confidence, np.float64)
    if floor_z is None:
        report.reason = "no floor found (fewer than 50 floor points): no rooms, no heights"
        report.objects = _objects(xyz, labels, conf, instances, matrix, yaw, None, None)
        return Layout(instances, report)
    grid = room_grid(xyz, labels, yaw, floor_z, params)
    report.objects = _objects(xyz, labels, conf, instances, matrix, yaw, floor_z, grid)
    if grid.labels.size == 0 or grid.labels.max() < 0:
        report.reason = "no room found: the floor is not closed by walls into any region"
        return Layout(instances, report)
    report.rooms = _rooms(xyz, labels, grid, floor_z)
    report.walls = _walls(xyz, labels, normals, instances, report, grid, floor_z, params, matrix)
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
) -> list[WallRecord]:
    """Wall planes along the plan's two axes, cut where the wall (or a door or window in it)
    has a gap, each with the rooms beside it and the doors and windows in it."""
    if normals is None:
        return []
    wall = np.flatnonzero(labels == WALL)
    plan = grid.plan_xy(xyz[wall])
    n_plan = grid.plan_xy(normals)  # the wall points' normals
    openings = np.flatnonzero(((labels == DOOR) | (labels == WINDOW)) & (instances >= 0))
    open_plan = grid.plan_xy(xyz[openings])
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
                places.append(_Place(axis, c, u0, u1, along[on], wall_z[facing][on]))
    objects = {o.id: o for o in report.objects}
    by_id = _groups(instances, openings)
    for w, place in zip(out, places, strict=True):
        _add_openings(w, place, by_id, objects, xyz, grid, floor_z)
    for r in report.rooms:
        r.walls = [w.id for w in out if r.id in w.rooms]
    return out


@dataclass(frozen=True)
class _Place:
    """A wall in the plan: its axis, offset and span, and its own points (along it, height)."""

    axis: int
    c: float
    u0: float
    u1: float
    u: np.ndarray
    z: np.ndarray


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
    grid: RoomGrid,
    floor_z: float,
) -> None:
    """Doors and windows lying in the wall's plane (within 0.3 m) and span. Their width is the
    gap they leave in the wall's own points at their height (an open door's leaf sticks out of
    the wall, so its points' extent is not the opening), else their points' extent."""
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
        if left.size and right.size and 0.3 < right.min() - left.max() < 3.0:
            lo, hi = float(left.max()), float(right.min())
        opening = OpeningRecord(
            object=obj_id,
            kind=obj.cls,
            width=round(hi - lo, 3),
            height=round(zhi - zlo, 3),
            sill=round(zlo - floor_z, 3),
        )
        wall.openings.append(opening)
        wall.net_area = round(max(wall.net_area - opening.width * opening.height, 0.0), 3)
