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
from jointseg.objects.openings import add_openings
from jointseg.objects.outline import fit_to_walls, room_outline
from jointseg.objects.params import DOOR, WALL, ObjectParams
from jointseg.objects.records import LayoutReport, ObjectRecord, RoomRecord, user_coords, vec
from jointseg.objects.rooms import (
    RoomGrid,
    ceiling_heights,
    floor_height,
    plan_labels,
    room_areas,
    room_grid,
)
from jointseg.objects.shapes import fits_class
from jointseg.objects.walls import join_door_pieces, wall_faces, wall_records

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
    grid = _plan(xyz, labels, structure, yaw, floor_z, params, barrier, barrier_normals)
    report.objects = _objects(xyz, labels, conf, instances, matrix, yaw, floor_z, grid)
    if grid.labels.size == 0 or grid.labels.max() < 0:
        report.reason = "no room found: the floor is not closed by walls into any region"
        return Layout(instances, report)
    report.rooms = _rooms(xyz, labels, grid, floor_z, structure)
    faces = [] if normals is None else wall_faces(xyz, labels, normals, instances, grid, params)
    if join_door_pieces(instances, labels, xyz, grid, faces, floor_z):
        report.objects = _objects(xyz, labels, conf, instances, matrix, yaw, floor_z, grid)
    wall = labels == WALL
    top = float(np.quantile(xyz[wall, 2], 0.99)) if wall.any() else floor_z
    report.walls = wall_records(faces, grid, floor_z, top, matrix)
    add_openings(
        report.walls, faces, report.objects, instances, labels, xyz, grid, floor_z, spacing
    )
    for r in report.rooms:
        r.walls = [w.id for w in report.walls if r.id in w.rooms]
    fit_to_walls(report.rooms, grid, faces)
    for obj in report.objects:
        if obj.room is not None and obj.room < len(report.rooms):
            report.rooms[obj.room].objects.append(obj.id)
    if not report.walls:
        report.reason = "no wall plane long enough was found"
    return Layout(instances, report)


def _plan(
    xyz: np.ndarray,
    labels: np.ndarray,
    structure: np.ndarray | None,
    yaw: float,
    floor_z: float,
    params: ObjectParams,
    barrier: np.ndarray,
    barrier_normals: np.ndarray | None,
) -> RoomGrid:
    """The rooms' grid, cut by the walls the structure reading confirms (``plan_labels``):
    their normals are those of ``barrier``'s points (wall and door labels), of which the
    confirmed walls and the doors are a subset."""
    cut = plan_labels(labels, structure)
    if barrier_normals is not None:
        barrier_normals = barrier_normals[((cut == WALL) | (cut == DOOR))[barrier]]
    return room_grid(xyz, cut, yaw, floor_z, params, barrier_normals)


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
                centroid=vec(user_coords(matrix, centroid)),
                box=[vec(c) for c in user_coords(matrix, corners)],
                size=vec(hi - lo),
                height_above_floor=round(float(lo[2] - (floor_z or 0.0)), 4),
                room=room,
                plausible=floor_z is None
                or fits_class(CLASS_NAMES[cls], vec(hi - lo), float(lo[2] - floor_z)),
            )
        )
    return out


def _rooms(
    xyz: np.ndarray,
    labels: np.ndarray,
    grid: RoomGrid,
    floor_z: float,
    structure: np.ndarray | None,
) -> list[RoomRecord]:
    areas = room_areas(grid)
    room = grid.room_of(xyz)
    heights = ceiling_heights(xyz, labels, room, floor_z, len(areas), structure)
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
