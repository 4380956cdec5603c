"""Wall faces in the floor plan: where they are, which side their body lies on, the rooms beside
them, and the door whose pieces the grouping parted.

A face is a histogram peak of the wall points that face along one of the plan's two axes,
cut where its points (or a door or window in it) leave a gap wider than ``WALL_GAP``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jointseg.objects.instances import rows_by_group
from jointseg.objects.params import DOOR, FLOOR, WALL, WINDOW, ObjectParams
from jointseg.objects.records import WallRecord, user_coords, vec
from jointseg.objects.rooms import RoomGrid
from jointseg.objects.wall_shape import body_side, joined_spans, thicknesses, wall_top

#: A wall plane is cut where its points (and its doors and windows) leave a gap this wide, m:
#: furniture in front of a wall hides stretches of it shorter than that.
WALL_GAP = 2.0
#: The widest door (a double door with its casings), m: door pieces further apart are two doors.
MAX_DOOR = 2.2


@dataclass(frozen=True)
class WallFace:
    """A wall face in the plan: its axis (the face lies at plan coordinate ``c`` along it),
    its span ``u0..u1`` along the other axis, the side of the face its wall's body lies on
    (+1 or -1 along ``axis``), and its own points (along it, height)."""

    axis: int
    c: float
    u0: float
    u1: float
    back: int
    u: np.ndarray
    z: np.ndarray

    def holds(self, plan: np.ndarray) -> bool:
        """Whether an object's points (plan coordinates) stand in this wall: a fifth of them
        within 0.3 m of its plane (an open door's leaf reaches into the room), their middle
        within its span."""
        near = np.abs(plan[:, self.axis] - self.c) < 0.3
        if np.mean(near) < 0.2:
            return False
        mid = float(np.median(plan[near, 1 - self.axis]))
        return self.u0 - 0.2 <= mid <= self.u1 + 0.2


def wall_faces(
    xyz: np.ndarray,
    labels: np.ndarray,
    normals: np.ndarray,
    instances: np.ndarray,
    grid: RoomGrid,
    params: ObjectParams,
    *,
    plan: np.ndarray | None = None,
) -> list[WallFace]:
    """The faces of the walls, along the plan's two axes (``normals``: of the wall points;
    ``plan``: every point's plan coordinates, when already found)."""
    points = _Planned(xyz, grid, plan)
    wall = np.flatnonzero(labels == WALL)
    plan = points.of(wall)
    n_plan = grid.plan_xy(normals)
    openings = np.flatnonzero(((labels == DOOR) | (labels == WINDOW)) & (instances >= 0))
    open_plan = points.of(openings)
    floor_plan = points.of(np.flatnonzero(labels == FLOOR))
    wall_z = xyz[wall, 2]
    out: list[WallFace] = []
    for axis in (0, 1):
        facing = np.flatnonzero(np.abs(n_plan[:, axis]) > 0.8)
        coord, along, z = plan[facing, axis], plan[facing, 1 - axis], wall_z[facing]
        for c in _planes(coord, min_count=max(50, int(0.002 * wall.size))):
            on = np.flatnonzero(np.abs(coord - c) < 0.06)
            face_u, face_z = along[on], z[on]
            own = np.sort(face_u)
            near_open = np.flatnonzero(np.abs(open_plan[:, axis] - c) < 0.3)
            # with no opening near, the runs are of its own points (the same sort)
            u = (
                own
                if near_open.size == 0
                else np.sort(np.r_[face_u, open_plan[near_open, 1 - axis]])
            )
            for u0, u1 in _runs(u, gap=WALL_GAP):
                # its own wall points must span a wall (a window's reveal faces along the wall
                # it is cut in, and a door's leaf beside it would lengthen the run)
                inside = own[np.searchsorted(own, u0) : np.searchsorted(own, u1, side="right")]
                span = float(inside[-1] - inside[0]) if inside.size else 0.0
                if span >= params.min_wall_length:
                    back = _back_side(floor_plan, axis, c, u0, u1)
                    out.append(WallFace(axis, c, u0, u1, back, face_u, face_z))
    return out


def join_door_pieces(
    instances: np.ndarray,
    labels: np.ndarray,
    xyz: np.ndarray,
    grid: RoomGrid,
    faces: list[WallFace],
    floor_z: float,
    *,
    plan: np.ndarray | None = None,
) -> int:
    """Join the pieces of one door in place; return how many joins were made.

    An open door's leaf and hinge-side casing touch, but the casing across the opening meets
    them only over the head, which a scan from below may miss: the grouping makes two objects,
    or leaves the far casing as crumbs too small to be one. Door pieces in one wall, side by
    side within a door's width, with no wall between them at mid height, are one door (crumbs
    join an object, never make one). Two doors in one wall have wall between them.
    """
    doors = np.flatnonzero(labels == DOOR)
    if doors.size == 0 or not (instances[doors] >= 0).any():
        return 0
    plan = _Planned(xyz, grid, plan).of(doors)
    ids = instances[doors]
    parts = {int(ids[p[0]]): p for p in rows_by_group(ids)}
    crumbs = np.flatnonzero(ids < 0)
    joined = 0
    for face in faces:
        pieces = _pieces(face, plan, parts, crumbs)
        band = (face.z > floor_z + 0.5) & (face.z < floor_z + 1.8)
        wall_u = np.sort(face.u[band])
        density = wall_u.size / max(face.u1 - face.u0, 1e-6)  # wall points per metre of face
        k = 0
        while k + 1 < len(pieces):
            (a0, b0, i0, r0), (a1, b1, i1, r1) = pieces[k], pieces[k + 1]
            lo, hi = b0 + 0.03, a1 - 0.03
            between = np.searchsorted(wall_u, hi) - np.searchsorted(wall_u, lo) if hi > lo else 0
            free = between <= 0.1 * density * max(hi - lo, 0.0)
            if max(b0, b1) - a0 > MAX_DOOR or not free or max(i0, i1) < 0:
                k += 1
                continue
            keep = i0 if i0 >= 0 else i1
            rows = np.r_[r0, r1]
            ids[rows] = keep
            if i0 >= 0 and i1 >= 0:  # two objects: the second joins the first
                joined += 1
                parts.pop(i1)
            parts[keep] = np.unique(np.r_[parts.get(keep, rows), rows])
            pieces[k] = (a0, max(b0, b1), keep, rows)
            del pieces[k + 1]
            k = max(k - 1, 0)  # the piece before may join the grown one now
        crumbs = np.flatnonzero(ids < 0)
    changed = ids != instances[doors]
    instances[doors[changed]] = ids[changed]
    return joined + int(changed.any())


class _Planned:
    """Points' plan coordinates by rows: read from every point's (``plan``) when given, else
    turned from the work frame."""

    def __init__(self, xyz: np.ndarray, grid: RoomGrid, plan: np.ndarray | None) -> None:
        self.xyz, self.grid, self.plan = xyz, grid, plan

    def of(self, rows: np.ndarray) -> np.ndarray:
        if self.plan is None:
            return self.grid.plan_xy(np.take(self.xyz, rows, axis=0))
        return np.take(self.plan, rows, axis=0)


def _pieces(
    face: WallFace, plan: np.ndarray, parts: dict[int, np.ndarray], crumbs: np.ndarray
) -> list[tuple[float, float, int, np.ndarray]]:
    """The door objects standing in a face, and its runs of crumbs (door points of no object,
    id -1), as (start, end along the wall, id, rows), sorted along the wall."""
    out: list[tuple[float, float, int, np.ndarray]] = []
    for i, rows in parts.items():
        if face.holds(plan[rows]):
            near = np.abs(plan[rows, face.axis] - face.c) < 0.3
            a, b = np.quantile(plan[rows[near], 1 - face.axis], [0.01, 0.99])
            out.append((float(a), float(b), i, rows))
    near = crumbs[np.abs(plan[crumbs, face.axis] - face.c) < 0.3]
    u = plan[near, 1 - face.axis]
    inside = (u > face.u0 - 0.2) & (u < face.u1 + 0.2)
    near, u = near[inside], u[inside]
    order = np.argsort(u)
    near, u = near[order], u[order]
    if u.size:
        cuts = np.flatnonzero(np.diff(u) > 0.1) + 1
        for run, along in zip(np.split(near, cuts), np.split(u, cuts), strict=True):
            out.append((float(along[0]), float(along[-1]), -1, run))
    out.sort(key=lambda p: (p[0], p[1]))
    return out


def wall_records(
    faces: list[WallFace],
    grid: RoomGrid,
    floor_z: float,
    top: float,
    matrix: np.ndarray,
    *,
    ceilings: dict[int, float | None] | None = None,
    default_thickness: float = 0.2,
) -> list[WallRecord]:
    """One record per face: its rectangle in user coordinates (its ends joined to the faces
    crossing it at the corners, its top at the ceiling of the rooms beside it where one was
    found, else at ``top``), the rooms on either side, and its wall's thickness."""
    thick, other = thicknesses(faces, default_thickness)
    spans = joined_spans(faces, thick)
    out = []
    for index, (face, span) in enumerate(zip(faces, spans, strict=True)):
        # rooms on either side: probe the grid 0.25 m off the wall's middle
        probes = []
        for side in (-0.25, 0.25):
            q = _point(face, (span.u0 + span.u1) / 2)
            q[face.axis] += side
            probes.append(q)
        beside = grid.room_of(np.c_[grid.work_xy(np.array(probes)), np.zeros(2)])
        rooms = sorted({int(r) for r in beside if r >= 0})
        wall_top_z = wall_top(rooms, ceilings or {}, floor_z, top)
        work = grid.work_xy(np.array([_point(face, span.u0), _point(face, span.u1)]))
        corners = np.array(
            [[*work[0], floor_z], [*work[1], floor_z], [*work[1], wall_top_z],
             [*work[0], wall_top_z]]
        )  # fmt: skip
        length, height = span.u1 - span.u0, wall_top_z - floor_z
        out.append(
            WallRecord(
                id=index,
                corners=[vec(v) for v in user_coords(matrix, corners)],
                length=round(length, 3),
                height=round(height, 3),
                area=round(length * height, 3),
                net_area=round(length * height, 3),
                rooms=rooms,
                thickness=round(thick[index], 3),
                thickness_measured=other[index] is not None,
                other_face=other[index],
                body_side=body_side(face),
                extends=(round(span.extend0, 3), round(span.extend1, 3)),
                joined=(span.joined0, span.joined1),
            )
        )
    return out


def _point(face: WallFace, u: float) -> np.ndarray:
    p = np.zeros(2)
    p[face.axis], p[1 - face.axis] = face.c, u
    return p


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
