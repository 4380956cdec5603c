"""Rooms from labelled points: the floor's footprint cut apart by the walls.

Everything happens on a grid over the levelled floor plan, turned to the walls' dominant
direction (:func:`jointseg.geometry.alignment.dominant_yaw`) so that walls run along grid rows
and columns. The footprint is every cell with floor points, and the cells under furniture that
stands on the floor (their floor is hidden, not missing). Wall and door cells, thickened by a
cell, are barriers, their door-wide gaps closed along each wall's own direction (never across
a corridor from one side to the other); the footprint minus the barriers splits into connected
regions, one per room; the barrier cells are then handed to the nearest room so each room
reaches its walls.
A room's area counts a cell on its outline as half a cell, which removes the bias of where the
outline falls inside its cells.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from jointseg.geometry.structure import MIN_FLOOR_POINTS, floor_level
from jointseg.objects.params import CEILING, CLUTTER, DOOR, FLOOR, WALL, ObjectParams

#: Furniture lower than this above the floor hides floor under it.
STANDS_BELOW = 0.5
#: Openings up to this wide (m) are closed when walls divide rooms.
DOOR_GAP = 1.9
#: Only wall lines at least this long (m) close a gap along their own direction.
LINE_MIN = 0.4
#: The points of a wall line may lie this far apart along it (m) and still be one line.
DOTS = 0.25
#: Cells of a wall's face handed to the room beside it.
HAND_CELLS = 3.0


@dataclass(frozen=True)
class RoomGrid:
    """The floor plan as a grid: a room id per cell (-1 none), and how to find cells."""

    labels: np.ndarray  # (H, W) int64
    origin: np.ndarray  # (2,) plan coordinates of cell (0, 0)'s corner
    cell: float
    yaw: float  # degrees: plan coordinates are the work frame turned by -yaw

    def plan_xy(self, xyz: np.ndarray) -> np.ndarray:
        """Work-frame points' plan coordinates (turned so walls run along the axes), (N, 2)."""
        return _turned(xyz, -self.yaw)

    def work_xy(self, plan: np.ndarray) -> np.ndarray:
        """Plan coordinates back to the work frame, (N, 2)."""
        return _turned(plan, self.yaw)

    def room_of(self, xyz: np.ndarray) -> np.ndarray:
        """The room id under each work-frame point, -1 outside every room, (N,)."""
        return self.room_of_plan(self.plan_xy(xyz))

    def room_of_plan(self, plan: np.ndarray) -> np.ndarray:
        """The room id at each plan position (:meth:`plan_xy`), -1 outside every room, (N,)."""
        if self.labels.size == 0:
            return np.full(len(plan), -1, dtype=np.int64)
        h, w = self.labels.shape
        i, j = (
            np.floor((plan[:, a] - self.origin[a]) / self.cell).astype(np.int64) for a in (0, 1)
        )
        inside = (i >= 0) & (i < h) & (j >= 0) & (j < w)
        np.clip(i, 0, h - 1, out=i)  # a cell for every point, read only where it is inside
        np.clip(j, 0, w - 1, out=j)
        i *= w
        i += j
        return np.where(inside, self.labels.ravel()[i], -1).astype(np.int64, copy=False)


def _turned(xy: np.ndarray, degrees: float) -> np.ndarray:
    """``[c x - s y, s x + c y]`` of the first two columns, turned by ``degrees``, (N, 2): each
    product and sum written in place (the same values as the expression, fewer temporaries)."""
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    x, y = np.asarray(xy[:, 0], dtype=np.float64), np.asarray(xy[:, 1], dtype=np.float64)
    out = np.empty((len(xy), 2))
    np.multiply(x, c, out=out[:, 0])
    out[:, 0] -= s * y
    np.multiply(x, s, out=out[:, 1])
    out[:, 1] += c * y
    return out


#: The least points of a structure reading's ceiling before it sets a room's ceiling height
#: (its floor: MIN_FLOOR_POINTS, jointseg.geometry.structure's).
MIN_CEILING_POINTS = 20


def floor_height(
    z: np.ndarray, labels: np.ndarray, structure: np.ndarray | None = None
) -> float | None:
    """Median height of the geometry's floor planes (``structure``) where it read at least 50
    floor points, else of the points labelled floor; None with fewer than 50 of either."""
    if structure is not None:
        level = floor_level(z, structure)
        if level is not None:
            return level
    floor = z[labels == FLOOR]
    return float(np.median(floor)) if floor.size >= MIN_FLOOR_POINTS else None


def plan_labels(labels: np.ndarray, structure: np.ndarray | None) -> np.ndarray:
    """The labels the floor plan is cut by: with a structure reading, a point labelled wall
    that the reading does not read as wall is something standing in the room, not one of its
    barriers. On ScanNet, tall furniture and unlabelled clutter voted wall cut rooms in two
    (bench/structure.py: rooms off by 10 to 19 % on four scans, within 6 % with this); on
    S3DIS the reading and the labels agree on the walls and nothing changes."""
    if structure is None:
        return labels
    out = labels.copy()
    out[(labels == WALL) & (structure != WALL)] = CLUTTER
    return out


def room_grid(
    xyz: np.ndarray,
    labels: np.ndarray,
    yaw: float,
    floor_z: float,
    params: ObjectParams,
    barrier_normals: np.ndarray | None = None,
    *,
    plan: np.ndarray | None = None,
) -> RoomGrid:
    """Split the floor plan into rooms (see the module's docstring).

    ``barrier_normals`` (of the wall and door points, in order) let each wall's gaps be closed
    along its own direction only, so a corridor narrower than a double door between two
    parallel walls is not closed shut; without them walls are closed along both directions.
    ``plan``: every point's plan coordinates, when already found.
    """
    cell = params.room_cell
    grid = RoomGrid(np.zeros((0, 0), np.int64), np.zeros(2), cell, yaw)
    height = xyz[:, 2] - floor_z
    floor = labels == FLOOR
    stands = (labels > WALL) & (labels != DOOR) & (height < STANDS_BELOW) & (height > -0.2)
    walls = (labels == WALL) | (labels == DOOR)
    raised = height > 0.1
    barrier = walls & raised
    used = floor | stands | barrier
    if not floor.any():
        return grid
    # only the points that count are binned (every count is of them)
    rows = np.flatnonzero(used)
    plan = grid.plan_xy(np.take(xyz, rows, axis=0)) if plan is None else np.take(plan, rows, 0)
    # each axis's quantiles on its own (the same values as along axis 0 of both)
    ends = np.array([np.quantile(plan[:, a], [0.0005, 0.9995]) for a in (0, 1)]).T
    lo, hi = ends[0] - 2 * cell, ends[1] + 2 * cell
    cells = _Cells(plan, lo, cell, tuple(np.ceil((hi - lo) / cell).astype(np.int64) + 1))
    floor, stands, barrier = floor[rows], stands[rows], barrier[rows]
    runs = None
    if barrier_normals is not None:
        # the used wall and door points are the raised ones: their normals, in the same order
        raised_walls = np.flatnonzero(raised[np.flatnonzero(walls)])
        n_plan = np.abs(grid.plan_xy(np.take(barrier_normals, raised_walls, axis=0)))
        votes = []
        for axis in (0, 1):  # a wall (or a door in it) runs along the axis its normal is across
            mask = np.zeros(len(rows), dtype=bool)
            mask[barrier] = n_plan[:, 1 - axis] > 0.85
            votes.append(cells.count(mask))
        runs = wall_lines(votes, cell)
    closed = close_walls(cells.count(barrier) > 0, runs, cell)
    seen = ndimage.binary_closing(
        (cells.count(floor) > 0) | (cells.count(stands) > 0), iterations=2
    )
    return RoomGrid(_regions(closed, seen, cell, params), lo, cell, yaw)


class _Cells:
    """Points' plan coordinates on the room grid: how many of a set fall in each cell (each
    point's cell found once, -1 off the grid)."""

    def __init__(
        self, plan: np.ndarray, lo: np.ndarray, cell: float, shape: tuple[int, int]
    ) -> None:
        self.shape = shape
        i, j = (np.floor((plan[:, a] - lo[a]) / cell).astype(np.int64) for a in (0, 1))
        ok = (i >= 0) & (j >= 0) & (i < shape[0]) & (j < shape[1])
        i *= shape[1]
        i += j
        self.flat = np.where(ok, i, -1)

    def count(self, mask: np.ndarray) -> np.ndarray:
        """Points of ``mask`` (over the points given) in each cell, shape ``self.shape``."""
        flat = self.flat[np.flatnonzero(mask)]
        flat = flat[np.flatnonzero(flat >= 0)]
        return np.bincount(flat, minlength=self.shape[0] * self.shape[1]).reshape(self.shape)


def wall_lines(votes: list[np.ndarray], cell: float) -> tuple[np.ndarray, np.ndarray]:
    """The cells of walls running along grid axis 0 and along axis 1, from the counts of
    wall points facing across each axis.

    A cell runs the way most of its points face: a stray point (a corner, a sill, an open
    door's leaf) facing across a corridor must not close the corridor. Only lines of
    ``LINE_MIN`` or more count, not a door's jamb or a wall's end seen edge-on; a far wall
    seen at a grazing angle is a dotted line, whose dots join first.
    """
    runs = [votes[0] > votes[1], votes[1] > votes[0]]
    line = max(int(round(LINE_MIN / cell)), 1)
    dots = max(int(round(DOTS / cell)), 1) | 1
    for axis in (0, 1):
        size, near = [1, 1], [1, 1]
        size[axis], near[axis] = line, dots
        joined = ndimage.binary_closing(np.pad(runs[axis], dots), structure=np.ones(near, bool))
        runs[axis] = ndimage.binary_opening(
            joined[dots:-dots, dots:-dots], structure=np.ones(size, bool)
        )
    return runs[0], runs[1]


def close_walls(
    walls: np.ndarray, runs: tuple[np.ndarray, np.ndarray] | None, cell: float
) -> np.ndarray:
    """The wall cells with their door-wide gaps closed (openings would join rooms, or let a
    room's inside leak out through a door): along each wall line (``runs``), from it to the
    next cell of any wall (a door by a corner), never between two walls across it (the two
    sides of a corridor); corners hidden on both walls completed. Without ``runs``, every wall
    cell is closed along both grid axes."""
    span = max(int(round(DOOR_GAP / cell)), 1) | 1

    def close(mask: np.ndarray, axis: int) -> np.ndarray:
        size = [1, 1]
        size[axis] = span
        padded = np.pad(mask, span)  # a closing erodes from the array's edge
        return ndimage.binary_closing(padded, np.ones(size, bool))[span:-span, span:-span]

    closed = walls.copy()
    if runs is None:
        for axis in (0, 1):
            closed |= close(walls, axis)
        return closed
    for axis in (0, 1):
        across = close(runs[1 - axis], axis) & ~runs[1 - axis]
        closed |= close(runs[axis] | runs[1 - axis], axis) & ~across
    return closed | complete_corners(closed & runs[0], closed & runs[1], span)


def _regions(closed: np.ndarray, seen: np.ndarray, cell: float, params: ObjectParams) -> np.ndarray:
    """A room id per cell (-1 none): the footprint (seen floor, or walled in) cut by the
    thickened walls into regions with enough seen floor, each filled to its orthogonal hull
    and given the wall-face cells beside it."""
    footprint = seen | walled_in(closed)
    thick = ndimage.binary_dilation(closed, iterations=1)
    regions, count = ndimage.label(footprint & ~thick)
    # a region counts as a room when enough of it is seen floor (not the inside of a wall)
    sizes = np.bincount(regions.ravel(), weights=seen.ravel(), minlength=count + 1) * cell * cell
    keep = np.flatnonzero(sizes >= params.min_room_area)
    keep = keep[keep > 0]
    renumber = np.full(count + 1, -1, dtype=np.int64)
    renumber[keep] = np.arange(keep.size)
    rooms = renumber[regions]
    # furniture against a wall hides both the floor and the wall behind it: fill each room to
    # its orthogonal hull (rectangles and L shapes are their own), where no other room is
    for r in range(keep.size):
        hull = surrounded(rooms == r) >= 3
        rooms[hull & (rooms < 0) & ~closed] = r
    # hand the footprint's cells next to a room (its wall faces) to the nearest room
    if keep.size:
        distance, (ii, jj) = ndimage.distance_transform_edt(rooms < 0, return_indices=True)
        near = footprint & thick & (rooms < 0) & (distance <= HAND_CELLS)
        rooms = np.where(near, rooms[ii, jj], rooms)
    return rooms


def complete_corners(along0: np.ndarray, along1: np.ndarray, span: int) -> np.ndarray:
    """The cells that join a wall line running along grid axis 0 and one running along axis
    1 into a corner, where each line stops short of the other's line by at most ``span``
    cells: a cupboard standing in a corner hides both walls' last metre or so."""
    out = np.zeros(along0.shape, dtype=bool)
    lines0 = ndimage.find_objects(ndimage.label(along0)[0])
    lines1 = ndimage.find_objects(ndimage.label(along1)[0])
    long0 = [b for b in lines0 if b is not None and b[0].stop - b[0].start >= span // 2]
    long1 = [b for b in lines1 if b is not None and b[1].stop - b[1].start >= span // 2]
    for a in long0:  # tens of wall lines, not cells
        for b in long1:
            # a runs along axis 0 across rows a[0], at columns a[1]; b the other way
            reach0 = _reach(a[0], b[0])  # rows from a's end to b's rows
            reach1 = _reach(b[1], a[1])  # columns from b's end to a's columns
            if reach0 is None or reach1 is None or reach0.stop - reach0.start > span:
                continue
            if reach1.stop - reach1.start > span or (_empty(reach0) and _empty(reach1)):
                continue
            out[reach0, a[1]] = True
            out[b[0], reach1] = True
    return out


def _reach(own: slice, other: slice) -> slice | None:
    """The cells along a line's own axis from its end to another line's cells (an empty
    slice where it already reaches them), None where the other lies beside its middle."""
    if own.stop <= other.start:
        return slice(own.stop, other.stop)
    if other.stop <= own.start:
        return slice(other.start, own.start)
    if own.start < other.start and other.stop < own.stop:
        return None  # a T: the other line meets this one's middle
    return slice(own.start, own.start)


def _empty(s: slice) -> bool:
    return s.stop <= s.start


def surrounded(mask: np.ndarray) -> np.ndarray:
    """Per cell, on how many of its four sides (along its row and column) ``mask`` has a cell:
    3 for a notch in a room's edge, 2 for the missing corner of an L."""
    count = np.zeros(mask.shape, dtype=np.int8)
    for axis in (0, 1):
        for flip in (False, True):
            m = np.flip(mask, axis) if flip else mask
            seen = np.maximum.accumulate(m, axis=axis)
            count += np.flip(seen, axis) if flip else seen
    return count


def walled_in(walls: np.ndarray) -> np.ndarray:
    """Cells with a wall on all four sides along their row and column: the inside of the walls,
    whatever the scan saw of the floor, and robust to gaps where walls fail to meet (a gap
    only matters to the one row or column through it, and a cell needs all four)."""
    inside = np.ones_like(walls)
    for axis in (0, 1):
        for flip in (False, True):
            w = np.flip(walls, axis) if flip else walls
            seen = np.maximum.accumulate(w, axis=axis)
            inside &= np.flip(seen, axis) if flip else seen
    return inside


def room_areas(grid: RoomGrid) -> np.ndarray:
    """Floor area of each room, m², outline cells counted as half cells."""
    n = int(grid.labels.max()) + 1 if grid.labels.size else 0
    if n == 0:
        return np.zeros(0)
    lab = grid.labels
    padded = np.pad(lab, 1, constant_values=-1)
    inner = lab.copy()
    for di, dj in ((0, 1), (2, 1), (1, 0), (1, 2)):
        shifted = padded[di : di + lab.shape[0], dj : dj + lab.shape[1]]
        inner = np.where(shifted != lab, -1, inner)
    edge = (lab >= 0) & (inner < 0)
    full = np.bincount(lab[lab >= 0], minlength=n).astype(np.float64)
    half = np.bincount(lab[edge], minlength=n).astype(np.float64)
    return (full - 0.5 * half) * grid.cell * grid.cell


def ceiling_heights(
    xyz: np.ndarray,
    labels: np.ndarray,
    room: np.ndarray,
    floor_z: float,
    n_rooms: int,
    structure: np.ndarray | None = None,
) -> np.ndarray:
    """Per room: the median height above the floor of the geometry's ceiling planes in it
    (``structure``), else of its points labelled ceiling; without either, the 99th percentile
    of the room's wall points (NaN when the room has none of these). The points are sorted
    by room once, so each room reads only its own."""
    out = np.full(n_rooms, np.nan)
    inside = np.flatnonzero((room >= 0) & (room < n_rooms))
    order = inside[np.argsort(room[inside], kind="stable")]
    bounds = np.searchsorted(room[order], np.arange(n_rooms + 1))
    z = xyz[order, 2]
    kinds = labels[order]
    planes_all = None if structure is None else structure[order] == CEILING
    for r in range(n_rooms):
        part = slice(bounds[r], bounds[r + 1])
        if planes_all is not None:
            planes = z[part][planes_all[part]]
            if planes.size >= MIN_CEILING_POINTS:
                out[r] = float(np.median(planes)) - floor_z
                continue
        ceiling = z[part][kinds[part] == CEILING]
        if ceiling.size >= 20:
            out[r] = float(np.median(ceiling)) - floor_z
            continue
        walls = z[part][kinds[part] == WALL]
        if walls.size >= 20:
            out[r] = float(np.quantile(walls, 0.99)) - floor_z
    return out
