"""Floor plans: spaces (rooms, corridor), wall faces, openings and free-space bookkeeping.

Everything here is 2D-and-a-bit and axis aligned in the scene frame; meshes are built from it in
:mod:`jointseg.synth.structure`. Spaces are unions of rectangles separated by walls of one
thickness, so the wall solid is simply "inside the building outline but in no space".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

Rect = tuple[float, float, float, float]  # x0, y0, x1, y1
Box3 = tuple[float, float, float, float, float, float]  # x0, y0, z0, x1, y1, z1


@dataclass
class WallFace:
    """One straight wall face of a space, seen from inside it.

    ``axis`` 0 means the face lies in the plane x = ``coord`` (normal along x), 1 means
    y = ``coord``; ``sign`` is the sign of the inward normal along that axis; ``u0..u1`` is the
    extent along the other horizontal axis. ``other`` is the space behind the wall, or None for
    an exterior wall.
    """

    space: int
    axis: int
    sign: int
    coord: float
    u0: float
    u1: float
    other: int | None = None

    @property
    def length(self) -> float:
        """Length of the face in metres."""
        return self.u1 - self.u0

    @property
    def normal(self) -> np.ndarray:
        """Inward unit normal (x, y)."""
        n = np.zeros(2)
        n[self.axis] = self.sign
        return n

    @property
    def yaw(self) -> float:
        """Yaw of a pose whose local +y is the inward normal (objects backed onto the wall)."""
        n = self.normal
        return math.atan2(n[1], n[0]) - math.pi / 2

    def point(self, u: float, offset: float = 0.0) -> np.ndarray:
        """Scene (x, y) of position ``u`` along the face, ``offset`` metres into the space."""
        p = np.zeros(2)
        p[self.axis] = self.coord + self.sign * offset
        p[1 - self.axis] = u
        return p


@dataclass
class Opening:
    """A door or window hole cut through a wall, described from the face of space A."""

    kind: str
    face: WallFace
    u0: float
    u1: float
    z0: float
    z1: float
    depth: float
    open_angle: float = 0.0

    @property
    def width(self) -> float:
        """Opening width in metres."""
        return self.u1 - self.u0

    def box(self) -> Box3:
        """The axis-aligned region removed from the wall solid."""
        f = self.face
        a0, a1 = (f.coord - self.depth, f.coord) if f.sign > 0 else (f.coord, f.coord + self.depth)
        if f.axis == 0:
            return (a0, self.u0, self.z0, a1, self.u1, self.z1)
        return (self.u0, a0, self.z0, self.u1, a1, self.z1)


@dataclass
class Space:
    """A room or corridor: a union of rectangles sharing one floor, ceiling and furnishing."""

    index: int
    kind: str
    rects: list[Rect]
    faces: list[WallFace] = field(default_factory=list)
    lights: list[tuple[float, float, float]] = field(default_factory=list)

    @property
    def bbox(self) -> Rect:
        """Bounding rectangle of the space."""
        r = np.array(self.rects)
        return (r[:, 0].min(), r[:, 1].min(), r[:, 2].max(), r[:, 3].max())

    @property
    def area(self) -> float:
        """Floor area in square metres (rectangles do not overlap)."""
        return float(sum((r[2] - r[0]) * (r[3] - r[1]) for r in self.rects))

    def contains(self, x: ArrayLike, y: ArrayLike, margin: float = 0.0) -> np.ndarray:
        """Whether points (x, y) lie inside the space, at least ``margin`` from its outline."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        inside = np.zeros(np.broadcast(x, y).shape, dtype=bool)
        for x0, y0, x1, y1 in self.rects:
            inside |= (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
        if margin > 0:
            for dx, dy in ((margin, 0), (-margin, 0), (0, margin), (0, -margin)):
                inside &= self.contains(x + dx, y + dy)
        return inside


@dataclass
class Plan:
    """A whole building level: spaces, openings and the common wall/ceiling dimensions."""

    spaces: list[Space]
    openings: list[Opening]
    height: float
    thickness: float

    @property
    def outline(self) -> Rect:
        """Outer bounding rectangle including the walls."""
        b = np.array([s.bbox for s in self.spaces])
        t = self.thickness
        return (b[:, 0].min() - t, b[:, 1].min() - t, b[:, 2].max() + t, b[:, 3].max() + t)


def _subtract(iv: list[tuple[float, float]], a: float, b: float) -> list[tuple[float, float]]:
    """Remove [a, b] from a list of disjoint intervals."""
    out = []
    for u0, u1 in iv:
        if b <= u0 or a >= u1:
            out.append((u0, u1))
            continue
        if a > u0:
            out.append((u0, a))
        if b < u1:
            out.append((b, u1))
    return out


def compute_faces(spaces: list[Space], thickness: float) -> None:
    """Fill ``space.faces``: rectangle sides not shared with the same space's other rectangles."""
    for sp in spaces:
        faces: list[WallFace] = []
        for i, (x0, y0, x1, y1) in enumerate(sp.rects):
            sides = [
                (0, 1, x0, y0, y1),
                (0, -1, x1, y0, y1),
                (1, 1, y0, x0, x1),
                (1, -1, y1, x0, x1),
            ]
            for axis, sign, coord, u0, u1 in sides:
                iv = [(u0, u1)]
                for j, r in enumerate(sp.rects):
                    if j == i:
                        continue
                    # r touches this side from the outside?
                    if axis == 0 and abs((r[2] if sign > 0 else r[0]) - coord) < 1e-9:
                        iv = _subtract(iv, r[1], r[3])
                    if axis == 1 and abs((r[3] if sign > 0 else r[1]) - coord) < 1e-9:
                        iv = _subtract(iv, r[0], r[2])
                for a, b in iv:
                    if b - a > 1e-6:
                        faces.append(WallFace(sp.index, axis, sign, coord, a, b))
        for f in faces:
            mid = f.point(0.5 * (f.u0 + f.u1), -(thickness + 0.01))
            for other in spaces:
                if other.index != sp.index and bool(other.contains(mid[0], mid[1])):
                    f.other = other.index
        sp.faces = faces


def place_opening(
    rng: np.random.Generator,
    face: WallFace,
    width: float,
    used: dict[int, list[tuple[float, float]]],
    key: int,
    margin: float = 0.35,
) -> tuple[float, float] | None:
    """Pick a free u-interval of ``width`` on ``face`` (``used`` tracks taken ones per face key)."""
    lo, hi = face.u0 + margin, face.u1 - margin - width
    if hi <= lo:
        return None
    taken = used.setdefault(key, [])
    for _ in range(20):
        a = float(rng.uniform(lo, hi))
        if all(a + width + margin <= t0 or a >= t1 + margin for t0, t1 in taken):
            taken.append((a, a + width))
            return a, a + width
    return None


def door_opening(
    rng: np.random.Generator,
    face: WallFace,
    used: dict[int, list[tuple[float, float]]],
    key: int,
    height: float,
    thickness: float,
    open_prob: float,
) -> Opening | None:
    """A single or double door on ``face``, sometimes standing open."""
    double = rng.random() < 0.2 and face.length > 4.0
    width = float(rng.uniform(1.5, 1.8) if double else rng.uniform(0.85, 1.05))
    span = place_opening(rng, face, width, used, key)
    if span is None:
        return None
    top = float(min(height - 0.2, rng.uniform(2.0, 2.2)))
    angle = float(rng.uniform(70.0, 105.0)) if rng.random() < open_prob else 0.0
    return Opening("door", face, span[0], span[1], 0.0, top, thickness, math.radians(angle))


def window_opening(
    rng: np.random.Generator,
    face: WallFace,
    used: dict[int, list[tuple[float, float]]],
    key: int,
    height: float,
    thickness: float,
) -> Opening | None:
    """A window hole on ``face`` with a plausible sill and head height."""
    width = float(rng.uniform(0.9, min(2.6, max(1.0, face.length - 0.8))))
    span = place_opening(rng, face, width, used, key, margin=0.4)
    if span is None:
        return None
    sill = float(rng.uniform(0.7, 1.0))
    top = float(min(height - 0.25, sill + rng.uniform(1.2, 1.9)))
    return Opening("window", face, span[0], span[1], sill, top, thickness)


class Occupancy:
    """Axis-aligned 3D boxes already taken in one space, for rejection-sampling placements."""

    def __init__(self, space: Space) -> None:
        self.space = space
        self._boxes: list[Box3] = []
        self._solid: list[bool] = []
        bx0, by0, bx1, by1 = space.bbox
        # Cells of the bounding box that are not in the space (the missing corner of an L).
        xs = sorted({bx0, bx1, *[v for r in space.rects for v in (r[0], r[2])]})
        ys = sorted({by0, by1, *[v for r in space.rects for v in (r[1], r[3])]})
        self._blocked: list[Rect] = []
        for xa, xb in zip(xs[:-1], xs[1:], strict=True):
            for ya, yb in zip(ys[:-1], ys[1:], strict=True):
                if not space.contains(0.5 * (xa + xb), 0.5 * (ya + yb)):
                    self._blocked.append((xa, ya, xb, yb))

    @property
    def boxes(self) -> np.ndarray:
        """(K, 6) taken boxes, keep-out zones (door swings, window fronts) included."""
        return np.array(self._boxes).reshape(-1, 6)

    def fits(self, box: Box3, margin: float = 0.05, wall_margin: float = 0.0) -> bool:
        """Whether ``box`` lies inside the space and clears every taken box by ``margin``."""
        x0, y0, z0, x1, y1, z1 = box
        bx0, by0, bx1, by1 = self.space.bbox
        if x0 < bx0 + wall_margin or y0 < by0 + wall_margin:
            return False
        if x1 > bx1 - wall_margin or y1 > by1 - wall_margin:
            return False
        for r in self._blocked:
            if x0 < r[2] + wall_margin and x1 > r[0] - wall_margin:
                if y0 < r[3] + wall_margin and y1 > r[1] - wall_margin:
                    return False
        if not self._boxes:
            return True
        b = np.asarray(self._boxes)
        hit = (x0 < b[:, 3] + margin) & (x1 > b[:, 0] - margin)
        hit &= (y0 < b[:, 4] + margin) & (y1 > b[:, 1] - margin)
        hit &= (z0 < b[:, 5]) & (z1 > b[:, 2])
        return not bool(hit.any())

    def add(self, box: Box3, solid: bool = True) -> None:
        """Mark ``box`` as taken (``solid=False`` for keep-out zones such as door swings)."""
        x0, y0, z0, x1, y1, z1 = (float(v) for v in box)
        self._boxes.append((x0, y0, z0, x1, y1, z1))
        self._solid.append(solid)


def keepouts_for(opening: Opening, space: Space, height: float) -> Box3 | None:
    """Region in front of an opening, on the side of ``space``, that furniture must leave free."""
    f = opening.face
    if space.index == f.space:
        sign, coord = f.sign, f.coord
    else:
        sign, coord = -f.sign, f.coord - f.sign * opening.depth
    if opening.kind == "door":
        reach, z0, z1 = 1.0, 0.0, min(height, opening.z1 + 0.25)
        pad = 0.25
    else:
        reach, z0, z1 = 0.35, opening.z0 - 0.05, opening.z1
        pad = 0.1
    a = (coord, coord + sign * reach)
    a0, a1 = min(a), max(a)
    u0, u1 = opening.u0 - pad, opening.u1 + pad
    if f.axis == 0:
        return (a0, u0, z0, a1, u1, z1)
    return (u0, a0, z0, u1, a1, z1)
