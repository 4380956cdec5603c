"""Doors and windows in their walls, and how wide each opening is.

The width a BIM model wants is the opening in the wall. A scan sees it three ways, tried in
this order for a door: a closed leaf between trims (casings) that stand off it
(:func:`inside_trims`); an open door's jambs, the surfaces facing along the wall inside its
body (:func:`between_jambs`); the gap the opening leaves in the wall's own points (for an
open door whose points are its leaf and one casing, a gap up to a door's width around
them). A window, and a door none of these can read, keeps its points' extent.
"""

from __future__ import annotations

import numpy as np

from jointseg.geometry.alignment import point_normals
from jointseg.objects.instances import rows_by_group
from jointseg.objects.params import DOOR, WINDOW
from jointseg.objects.records import ObjectRecord, OpeningRecord, SetAside, WallRecord
from jointseg.objects.rooms import RoomGrid
from jointseg.objects.walls import MAX_DOOR, WallFace

#: A door's trim stands at least this far (m) in front of or behind its leaf.
TRIM_STEP = 0.004
#: Trims (casings, architraves) are at most this wide, m: a wider run is a leaf.
MAX_TRIM = 0.2
#: Profile bins along the opening, m.
STEP = 0.02


#: A door (its opening) this narrow, wide, low or high is no door (single or double leaf), m.
DOOR_WIDTH = (0.6, 1.8)
DOOR_HEIGHT = (1.8, 2.6)
#: A door's points starting at most this far above the floor (its foot hidden by furniture,
#: or read as wall) open the wall from the floor, m.
DOOR_REACH = 1.0
#: A door's opening starts on the floor: a sill above this is no door's, m.
DOOR_MAX_SILL = 0.3
#: A window's least width and height, and the least sill that is not the floor, m.
WINDOW_MIN = 0.2
WINDOW_MIN_SILL = 0.1
#: A window's top may pass its wall's top by this much (the wall's top is measured), m.
WINDOW_TOP_SLACK = 0.05


def opening_problem(opening: OpeningRecord, wall_height: float) -> str | None:
    """Why ``opening`` cannot be the door or window its label says, None when it can (what a
    BIM model may hold: a door is taller than wide, 0.6-1.8 m wide and 1.8-2.6 m high; a
    window stands in the wall above the floor and below the wall's top)."""
    w, h = opening.width, opening.height
    if opening.kind == "door":
        if w >= h:
            return f"wider ({w:.2f} m) than high ({h:.2f} m): no door is"
        if not DOOR_WIDTH[0] <= w <= DOOR_WIDTH[1]:
            return f"{w:.2f} m wide: a door is {DOOR_WIDTH[0]}-{DOOR_WIDTH[1]} m"
        if opening.sill > DOOR_MAX_SILL:
            return f"starts {opening.sill:.2f} m above the floor: a door stands on it"
        if not DOOR_HEIGHT[0] <= h <= DOOR_HEIGHT[1]:
            return f"{h:.2f} m high: a door is {DOOR_HEIGHT[0]}-{DOOR_HEIGHT[1]} m"
        return None
    if w < WINDOW_MIN or h < WINDOW_MIN:
        return f"{w:.2f} x {h:.2f} m: too small for a window"
    if opening.sill < WINDOW_MIN_SILL:
        return f"touches the floor (sill {opening.sill:.2f} m): a window stands above it"
    if opening.sill + h > wall_height + WINDOW_TOP_SLACK:
        return f"its top ({opening.sill + h:.2f} m) is above its wall's ({wall_height:.2f} m)"
    return None


def add_openings(
    walls: list[WallRecord],
    faces: list[WallFace],
    objects: list[ObjectRecord],
    instances: np.ndarray,
    labels: np.ndarray,
    xyz: np.ndarray,
    grid: RoomGrid,
    floor_z: float,
    spacing: float,
    *,
    plan: np.ndarray | None = None,
    starts: list[float] | None = None,
) -> list[SetAside]:
    """Each door and window to the wall it stands in, with its width, height, sill and place
    along the wall (from ``starts``: each wall's first corner along its face, the face's own
    start when not given); the wall's net area loses the opening (``plan``: every point's plan
    coordinates, when already found). Returns the doors and windows set aside: in no wall, or
    of a size no door or window has (:func:`opening_problem`)."""
    rows = np.flatnonzero(((labels == DOOR) | (labels == WINDOW)) & (instances >= 0))
    if rows.size == 0:
        return []
    # fragments too: a door's upper half in a wall, its lower half hidden, is a door's opening
    kinds = {o.id: o.cls for o in objects if o.cls in ("door", "window")}
    starts = [f.u0 for f in faces] if starts is None else starts
    points = np.take(xyz, rows, axis=0)
    normals = _LazyNormals(points, spacing, grid)
    plan = grid.plan_xy(points) if plan is None else np.take(plan, rows, axis=0)
    aside: list[SetAside] = []
    for part in rows_by_group(instances[rows]):
        obj = int(instances[rows[part[0]]])
        if obj not in kinds:
            continue
        holding = [k for k, face in enumerate(faces) if face.holds(plan[part])]
        if not holding:
            aside.append(SetAside(object=obj, kind=kinds[obj], reason="in no wall found"))
            continue
        # the face nearest its points (both faces of a wall between two rooms hold it)
        k = min(holding, key=lambda k: _offset(faces[k], plan[part]))
        wall, face = walls[k], faces[k]
        z = points[part, 2]
        zlo, zhi = (float(v) for v in np.quantile(z, [0.01, 0.99]))
        door = kinds[obj] == "door"
        # only a door's span reads its points' normals: a window's needs none
        part_normals = normals.of(part) if door else np.zeros((part.size, 2))
        lo, hi = opening_span(face, plan[part], z, part_normals, door)
        if door and zlo - floor_z <= DOOR_REACH:
            zlo = floor_z  # a door's opening starts at the floor, seen or hidden
        opening = OpeningRecord(
            object=obj,
            kind=kinds[obj],
            width=round(hi - lo, 3),
            height=round(zhi - zlo, 3),
            sill=round(zlo - floor_z, 3),
            offset=round(lo - starts[k], 3),
        )
        problem = opening_problem(opening, wall.height)
        if problem is not None:
            aside.append(SetAside(object=obj, kind=kinds[obj], reason=problem))
            continue
        wall.openings.append(opening)
        wall.net_area = round(max(wall.net_area - opening.width * opening.height, 0.0), 3)
    return aside


class _LazyNormals:
    """The openings' plan normals (:func:`point_normals` of all their points, turned to the
    plan), found on the first door that needs them: a scan with no door in a wall never
    pays for them."""

    def __init__(self, xyz: np.ndarray, spacing: float, grid: RoomGrid) -> None:
        self.xyz, self.spacing, self.grid = xyz, spacing, grid
        self.normals: np.ndarray | None = None

    def of(self, rows: np.ndarray) -> np.ndarray:
        if self.normals is None:
            self.normals = self.grid.plan_xy(point_normals(self.xyz, self.spacing))
        return self.normals[rows]


def _offset(face: WallFace, plan: np.ndarray) -> float:
    return abs(float(np.median(plan[:, face.axis])) - face.c)


def opening_span(
    face: WallFace, plan: np.ndarray, z: np.ndarray, normals: np.ndarray, door: bool
) -> tuple[float, float]:
    """Where an opening begins and ends along its wall (see the module's docstring)."""
    axis = face.axis
    near = np.abs(plan[:, axis] - face.c) < 0.3  # not an open leaf's far end
    u = plan[:, 1 - axis]
    lo, hi = (float(v) for v in np.quantile(u[near], [0.01, 0.99]))
    zlo, zhi = (float(v) for v in np.quantile(z, [0.01, 0.99]))
    mid = (lo + hi) / 2
    if door:
        band = (z > zlo + 0.3 * (zhi - zlo)) & (z < zhi - 0.3 * (zhi - zlo)) & near
        facing = band & (np.abs(normals[:, axis]) > 0.8)
        trims = inside_trims(u[facing], plan[facing, axis], lo, hi)
        if trims is not None:
            return trims
        through = open_gap(u[facing])
        if through is not None:
            return through
        depth = face.back * (plan[:, axis] - face.c)  # > 0: inside the wall's body
        along = band & (np.abs(normals[:, 1 - axis]) > 0.8) & (depth > 0.01) & (depth < 0.6)
        jambs = between_jambs(u[along], mid)
        if jambs is not None:
            return jambs
        high = (z > zlo + 0.3 * (zhi - zlo)) & (z < zhi - 0.3 * (zhi - zlo))
        leaf = leaf_length(plan[high], face)
        if leaf is not None:
            hinge = lo if abs(mid - lo) < abs(mid - hi) else hi
            return (hinge, hinge + leaf) if hinge == lo else (hinge - leaf, hinge)
    band = (face.z > zlo + 0.25 * (zhi - zlo)) & (face.z < zhi - 0.25 * (zhi - zlo))
    left, right = face.u[band & (face.u < mid)], face.u[band & (face.u > mid)]
    if left.size and right.size:
        gap = float(left.max()), float(right.min())
        # trims hide the wall up to a closed opening's outer edges: a gap wider than its
        # points is missing wall; but an open door's points may be its leaf and one casing
        within = gap[0] >= lo - 0.05 and gap[1] <= hi + 0.05
        holds = gap[0] <= lo + 0.05 and gap[1] >= hi - 0.05 and gap[1] - gap[0] <= MAX_DOOR
        if 0.3 < gap[1] - gap[0] < 3.0 and (within or door and holds):
            return gap
    return lo, hi


def inside_trims(
    u: np.ndarray, depth: np.ndarray, lo: float, hi: float
) -> tuple[float, float] | None:
    """The opening between a closed door's trims, None where no leaf fills it (open).

    Across the opening (2 cm bins along the wall, the median depth of the surfaces facing
    the room) a trim is a run at an end, at most ``MAX_TRIM`` wide, whose depth stands off
    the leaf between by more than the leaf's own spread (at least ``TRIM_STEP``): the
    opening begins where that run ends. An end without such a run keeps its measured edge.
    """
    n = int(np.ceil((hi - lo) / STEP))
    if n < 12:
        return None
    bins = np.floor((u - lo) / STEP).astype(np.int64)
    keep = (bins >= 0) & (bins < n)
    order = np.argsort(bins[keep], kind="stable")
    bins, depth = bins[keep][order], depth[keep][order]
    starts = np.searchsorted(bins, np.arange(n))
    ends = np.searchsorted(bins, np.arange(n), side="right")
    profile = np.full(n, np.nan)
    for b in np.flatnonzero(ends - starts >= 3):  # tens of bins, not points
        profile[b] = np.median(depth[starts[b] : ends[b]])
    seen = np.flatnonzero(~np.isnan(profile))
    inner = seen[(seen >= n // 4) & (seen < 3 * n // 4)]
    if inner.size < max(n // 4, 4):
        return None  # the middle is open: no leaf
    centre = profile[inner]
    middle = float(np.median(centre))
    least = max(TRIM_STEP, 4.0 * float(np.median(np.abs(centre - middle))))
    edges = [lo, hi]
    for side in (0, 1):
        walk = seen if side == 0 else seen[::-1]
        trim = float(np.median(profile[walk[:2]]))
        if abs(trim - middle) < least:
            continue
        last = None
        for b in walk:  # the end's run: bins nearer the trim's depth than the leaf's
            if abs(profile[b] - trim) >= abs(profile[b] - middle):
                break
            last = b
        if last is None:
            continue
        edge = lo + (last + 1) * STEP if side == 0 else lo + last * STEP
        if abs(edge - edges[side]) <= MAX_TRIM:
            edges[side] = edge
    if edges[1] - edges[0] < 0.3:
        return lo, hi
    return edges[0], edges[1]


def between_jambs(u: np.ndarray, mid: float) -> tuple[float, float] | None:
    """The opening between an open door's jambs: the innermost surfaces facing along the
    wall inside its body, left and right of the middle (``u``: those surfaces' points along
    the wall), None unless both are seen. A double door's meeting edges lie mid-way, and no
    door is narrower than 0.4 m, so the 0.2 m either side of the middle is left out."""
    left, right = u[u < mid - 0.2], u[u > mid + 0.2]
    if left.size < 10 or right.size < 10:
        return None
    return float(np.quantile(left, 0.98)), float(np.quantile(right, 0.02))


def open_gap(u: np.ndarray) -> tuple[float, float] | None:
    """An open door seen through: the widest gap, 0.4 m or more, between its surfaces that
    face the room (its casings and the front edges of its lining), None without one."""
    if u.size < 20:
        return None
    u = np.sort(u)
    gaps = np.diff(u)
    k = int(np.argmax(gaps))
    if gaps[k] < 0.4:
        return None
    return float(u[k]), float(u[k + 1])


def leaf_length(plan: np.ndarray, face: WallFace) -> float | None:
    """An open leaf's width: the length of its points standing out of the wall into the room
    (more than 0.1 m off the face), along their main direction and back to the face; None
    without 30 such points or for a leaf narrower than 0.4 m or wider than 1.3 m."""
    off = -face.back * (plan[:, face.axis] - face.c)  # > 0: in the room
    out = plan[off > 0.1]
    if len(out) < 30:
        return None
    centred = out - out.mean(axis=0)
    direction = np.linalg.svd(centred, full_matrices=False)[2][0]
    t = centred @ direction
    sine = abs(direction[face.axis])  # how steeply the leaf leaves the wall
    if sine < 0.3:
        return None
    length = float(t.max() - t.min()) + float(off[off > 0.1].min()) / sine
    return length if 0.4 <= length <= 1.3 else None
