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
from jointseg.objects.instances import find_instances, group_order
from jointseg.objects.openings import add_openings
from jointseg.objects.outline import fit_to_walls, room_outline
from jointseg.objects.params import CEILING, DOOR, WALL, ObjectParams
from jointseg.objects.records import (
    LayoutReport,
    ObjectRecord,
    RoomRecord,
    SetAside,
    WallRecord,
    user_coords,
    vec,
)
from jointseg.objects.rooms import (
    RoomGrid,
    ceiling_heights,
    floor_height,
    plan_labels,
    room_areas,
    room_grid,
)
from jointseg.objects.shapes import fits_class
from jointseg.objects.wall_shape import joined_spans
from jointseg.objects.walls import WallFace, join_door_pieces, wall_faces, wall_records

log = logging.getLogger(__name__)


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
    structure: np.ndarray | None = None,
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
    structure : ndarray of shape (N,), optional
        The geometry's structure reading per point (floor, ceiling or wall class, -1 for
        none; ``GeometryResult.structure``): the floor level and the rooms' ceiling heights
        come from its floor and ceiling planes where it has them, so they hold where the
        labels are poor, and the floor plan is cut only by the wall points it reads as wall
        (furniture voted wall cuts no room in two); default: from the labels alone.
    """
    params = params or ObjectParams()
    matrix = np.eye(4) if to_user is None else np.asarray(to_user, dtype=np.float64)
    instances = find_instances(xyz, labels, spacing, params)
    floor_z = floor_height(xyz[:, 2], labels, structure)
    barrier, barrier_normals, normals = _barrier_normals(xyz, labels, spacing)
    yaw = dominant_yaw(normals) if normals is not None else 0.0
    report = LayoutReport(floor_z=floor_z, yaw=yaw, to_user=matrix.tolist())
    # every point's plan coordinates once: each step below reads its own points' rows
    plan = RoomGrid(np.zeros((0, 0), np.int64), np.zeros(2), 1.0, yaw).plan_xy(xyz)
    if floor_z is None:
        report.reason = "no floor found (fewer than 50 floor points): no rooms, no heights"
        report.objects = _objects(xyz, labels, confidence, instances, matrix, yaw, None, None, plan)
        return Layout(instances, report)
    grid = _plan(xyz, labels, structure, yaw, floor_z, params, barrier, barrier_normals, plan)
    report.objects = _objects(xyz, labels, confidence, instances, matrix, yaw, floor_z, grid, plan)
    if grid.labels.size == 0 or grid.labels.max() < 0:
        report.reason = "no room found: the floor is not closed by walls into any region"
        return Layout(instances, report)
    report.rooms = _rooms(xyz, labels, grid, floor_z, structure, plan)
    faces = (
        []
        if normals is None
        else wall_faces(xyz, labels, normals, instances, grid, params, plan=plan)
    )
    doors = np.flatnonzero(labels == DOOR)
    before = instances[doors]
    if join_door_pieces(instances, labels, xyz, grid, faces, floor_z, plan=plan):
        # only the door objects the join changed (or removed) are measured again
        moved = np.flatnonzero(instances[doors] != before)
        ids = np.unique(np.r_[before[moved], instances[doors[moved]]])
        ids = ids[ids >= 0]
        again = _objects(
            xyz, labels, confidence, instances, matrix, yaw, floor_z, grid, plan, only=ids
        )
        kept = [o for o in report.objects if o.id not in set(ids.tolist())]
        report.objects = sorted(kept + again, key=lambda o: o.id)
    _walls_and_openings(report, faces, instances, labels, xyz, grid, floor_z, spacing, params,
                        plan, matrix)  # fmt: skip
    for r in report.rooms:
        r.walls = [w.id for w in report.walls if r.id in w.rooms]
    fit_to_walls(report.rooms, grid, faces)
    for obj in report.objects:
        if obj.room is not None and obj.room < len(report.rooms):
            report.rooms[obj.room].objects.append(obj.id)
    if not report.walls:
        report.reason = "no wall plane long enough was found"
    return Layout(instances, report)


def _walls_and_openings(report: LayoutReport, faces: list[WallFace], instances: np.ndarray,
                        labels: np.ndarray, xyz: np.ndarray, grid: RoomGrid, floor_z: float,
                        spacing: float, params: ObjectParams, plan: np.ndarray,
                        matrix: np.ndarray) -> None:  # fmt: skip
    """The walls' records (up to their rooms' ceilings, thickness, corners) and the doors and
    windows in them; those set aside, and why."""
    wall = labels == WALL
    top = float(np.quantile(xyz[np.flatnonzero(wall), 2], 0.99)) if wall.any() else floor_z
    ceilings = {r.id: r.ceiling_height for r in report.rooms}
    report.walls = wall_records(faces, grid, floor_z, top, matrix, ceilings=ceilings,
                                default_thickness=params.wall_thickness)  # fmt: skip
    report.wall_thickness = params.wall_thickness if report.walls else None
    starts = [s.u0 for s in joined_spans(faces, [w.thickness for w in report.walls])]
    hosted = add_openings(report.walls, faces, report.objects, instances, labels, xyz, grid,
                          floor_z, spacing, plan=plan, starts=starts)  # fmt: skip
    report.set_aside = fragments(report.objects, report.walls) + hosted


def fragments(objects: list[ObjectRecord], walls: list[WallRecord]) -> list[SetAside]:
    """The doors and windows whose box has no door's or window's shape (see
    :mod:`jointseg.objects.shapes`) and that fill no opening in a wall."""
    hosted = {o.object for w in walls for o in w.openings}
    return [
        SetAside(object=o.id, kind=o.cls, reason="a fragment: its box has no "
                 f"{o.cls}'s shape ({o.size[2]:.2f} m high, {o.height_above_floor:.2f} m up)")
        for o in objects
        if o.cls in ("door", "window") and not o.plausible and o.id not in hosted
    ]  # fmt: skip


def _barrier_normals(
    xyz: np.ndarray, labels: np.ndarray, spacing: float
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The wall and door points (the rooms' barriers), their normals and the wall points'
    normals (None with fewer than 10 wall points): the walls' direction, planes and the
    barriers need no others."""
    walls_mask = labels == WALL
    barrier = walls_mask | (labels == DOOR)
    barrier_rows = np.flatnonzero(barrier)
    barrier_normals = (
        point_normals(np.take(xyz, barrier_rows, axis=0), spacing)
        if np.count_nonzero(walls_mask) >= 10
        else None
    )
    wall_of_barrier = np.flatnonzero(walls_mask[barrier_rows])
    normals = None if barrier_normals is None else np.take(barrier_normals, wall_of_barrier, 0)
    return barrier, barrier_normals, normals


def _plan(
    xyz: np.ndarray,
    labels: np.ndarray,
    structure: np.ndarray | None,
    yaw: float,
    floor_z: float,
    params: ObjectParams,
    barrier: np.ndarray,
    barrier_normals: np.ndarray | None,
    plan: np.ndarray | None = None,
) -> RoomGrid:
    """The rooms' grid, cut by the walls the structure reading confirms (``plan_labels``):
    their normals are those of ``barrier``'s points (wall and door labels), of which the
    confirmed walls and the doors are a subset."""
    cut = plan_labels(labels, structure)
    if barrier_normals is not None:
        confirmed = ((cut == WALL) | (cut == DOOR))[np.flatnonzero(barrier)]
        barrier_normals = np.take(barrier_normals, np.flatnonzero(confirmed), axis=0)
    return room_grid(xyz, cut, yaw, floor_z, params, barrier_normals, plan=plan)


def _objects(
    xyz: np.ndarray,
    labels: np.ndarray,
    confidence: np.ndarray | None,
    instances: np.ndarray,
    matrix: np.ndarray,
    yaw: float,
    floor_z: float | None,
    grid: RoomGrid | None,
    plan: np.ndarray,
    only: np.ndarray | None = None,
) -> list[ObjectRecord]:
    """A record per object (per object of ``only`` when given; ``plan``: every point's plan
    coordinates). The points are sorted by object once and every box, class and room is
    found for all objects together; the means stay per object (a slice each), so they are
    summed in the same order as one object's own points would be."""
    chosen = instances >= 0 if only is None else np.isin(instances, only)
    valid = np.flatnonzero(chosen)
    if valid.size == 0:
        return []
    rows = valid[group_order(instances[valid], int(instances[valid].max()) + 1)]
    ids = instances[rows]
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    ends = np.r_[starts[1:], rows.size]
    helper = grid or RoomGrid(np.zeros((0, 0), np.int64), np.zeros(2), 1.0, yaw)
    p = np.take(xyz, rows, axis=0)
    flat = np.take(plan, rows, axis=0)
    lo = np.column_stack(
        [np.minimum.reduceat(flat, starts, axis=0), np.minimum.reduceat(p[:, 2], starts)]
    )
    hi = np.column_stack(
        [np.maximum.reduceat(flat, starts, axis=0), np.maximum.reduceat(p[:, 2], starts)]
    )
    # the 8 corners of each box: z (low, high) outer, then the plan's 4 corners in turn
    cx = np.where(np.array([0, 1, 1, 0] * 2, dtype=bool), hi[:, None, 0], lo[:, None, 0])
    cy = np.where(np.array([0, 0, 1, 1] * 2, dtype=bool), hi[:, None, 1], lo[:, None, 1])
    cz = np.where(np.array([0] * 4 + [1] * 4, dtype=bool), hi[:, None, 2], lo[:, None, 2])
    work = helper.work_xy(np.column_stack([cx.ravel(), cy.ravel()]))
    corners = np.stack([work[:, 0], work[:, 1], cz.ravel()], axis=1).reshape(-1, 8, 3)
    segment = np.repeat(np.arange(starts.size), ends - starts)
    votes = np.bincount(segment * NUM_CLASSES + labels[rows], minlength=starts.size * NUM_CLASSES)
    classes = votes.reshape(-1, NUM_CLASSES).argmax(axis=1)
    centroids = np.stack([p[a:b].mean(axis=0) for a, b in zip(starts, ends, strict=True)])
    rooms = np.full(starts.size, -1, dtype=np.int64)
    if grid is not None and grid.labels.size:
        rooms = grid.room_of(centroids)
    c = np.ones(rows.size) if confidence is None else np.asarray(confidence[rows], np.float64)
    out = []
    for k, (a, b) in enumerate(zip(starts, ends, strict=True)):
        cls = CLASS_NAMES[int(classes[k])]
        size = vec(hi[k] - lo[k])
        out.append(
            ObjectRecord(
                id=int(ids[a]),
                cls=cls,
                points=int(b - a),
                confidence=round(float(c[a:b].mean()), 4),
                centroid=vec(user_coords(matrix, centroids[k])),
                box=[vec(v) for v in user_coords(matrix, corners[k])],
                size=size,
                height_above_floor=round(float(lo[k, 2] - (floor_z or 0.0)), 4),
                room=int(rooms[k]) if rooms[k] >= 0 else None,
                plausible=floor_z is None or fits_class(cls, size, float(lo[k, 2] - floor_z)),
            )
        )
    return out


def _rooms(
    xyz: np.ndarray,
    labels: np.ndarray,
    grid: RoomGrid,
    floor_z: float,
    structure: np.ndarray | None,
    plan: np.ndarray,
) -> list[RoomRecord]:
    areas = room_areas(grid)
    # only ceiling and wall points set a height: only they are placed in rooms
    tall = (labels == CEILING) | (labels == WALL)
    if structure is not None:
        tall |= structure == CEILING
    rows = np.flatnonzero(tall)
    heights = ceiling_heights(
        np.take(xyz, rows, axis=0),
        labels[rows],
        grid.room_of_plan(np.take(plan, rows, axis=0)),
        floor_z,
        len(areas),
        None if structure is None else structure[rows],
    )
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
