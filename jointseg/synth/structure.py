"""The building shell: walls with real openings, floors, ceilings, doors and windows.

Walls are solid: the level's outline minus its spaces, cut into boxes on the grid of all space
edges and carved around door and window holes, so reveals, lintels and sills exist and a door
seen from a corridor is a recessed panel, not a painted rectangle. Only box faces that look into
a space or an opening are emitted, each tagged with the instance of the wall plane it belongs to.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from jointseg.classes import CLASS_INDEX
from jointseg.synth import appearance as ap
from jointseg.synth.layout import Box3, Opening, Plan, Space
from jointseg.synth.meshes import MeshBuilder, Pose

WALL, FLOOR, CEILING = CLASS_INDEX["wall"], CLASS_INDEX["floor"], CLASS_INDEX["ceiling"]
DOOR, WINDOW = CLASS_INDEX["door"], CLASS_INDEX["window"]
SLAB = 0.12  # floor / ceiling slab thickness (only the inner face is ever seen)


class Ids:
    """Hands out object ids (the ``instance`` field), unique within one scan."""

    def __init__(self) -> None:
        self._next = 0

    def __call__(self) -> int:
        self._next += 1
        return self._next


@dataclass
class SpaceLook:
    """Paint and floor finish shared by a space's surfaces."""

    wall: np.ndarray
    floor: np.ndarray
    floor_material: int
    ceiling: np.ndarray
    ceiling_material: int


def space_look(rng: np.random.Generator, corridor: bool = False) -> SpaceLook:
    """Draw a space's wall paint, floor finish and ceiling type."""
    wall = ap.sample_colour(rng, "wall")
    floor = ap.sample_colour(rng, "floor")
    brownish = floor[0] > floor[2] + 0.12
    if brownish:
        fmat = ap.WOOD if rng.random() < 0.6 else ap.CARPET
    else:
        fmat = int(rng.choice([ap.CARPET, ap.TILE, ap.PLAIN], p=[0.5, 0.35, 0.15]))
    if corridor and fmat == ap.CARPET and rng.random() < 0.5:
        fmat = ap.TILE
    ceiling = ap.sample_colour(rng, "ceiling")
    cmat = ap.CEILING_TILE if rng.random() < 0.6 else ap.PLAIN
    return SpaceLook(wall, floor, fmat, ceiling, cmat)


def _carve(cell: Box3, holes: np.ndarray) -> list[Box3]:
    """Split a wall box on the hole boundaries and drop the pieces inside a hole."""
    lo, hi = np.array(cell[:3]), np.array(cell[3:])
    if holes.size:
        ov = np.all((holes[:, :3] < hi - 1e-9) & (holes[:, 3:] > lo + 1e-9), axis=1)
        holes = holes[ov]
    if not holes.size:
        return [cell]
    cuts = []
    for a in range(3):
        v = np.concatenate([[lo[a], hi[a]], holes[:, a], holes[:, a + 3]])
        cuts.append(np.unique(np.clip(v, lo[a], hi[a])))
    out: list[Box3] = []
    for (x0, x1), (y0, y1), (z0, z1) in itertools.product(
        *[list(zip(c[:-1], c[1:], strict=True)) for c in cuts]
    ):
        c = np.array([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2])
        if np.any(np.all((holes[:, :3] < c) & (holes[:, 3:] > c), axis=1)):
            continue
        out.append((x0, y0, z0, x1, y1, z1))
    return out


def build_shell(
    plan: Plan,
    mb: MeshBuilder,
    ids: Ids,
    looks: list[SpaceLook],
    rng: np.random.Generator,
) -> None:
    """Add walls, floors and ceilings of every space (one instance per wall plane)."""
    holes = np.array([o.box() for o in plan.openings]).reshape(-1, 6)
    b = _wall_boxes(plan, holes)
    lo, hi = b[:, :3], b[:, 3:]
    face_inst, face_col, mask = _wall_faces(plan, lo, hi, holes, _WallPlanes(ids, looks, rng))
    keep = mask.any(axis=1)
    mb.add_boxes(
        (0.5 * (lo + hi))[keep],
        (hi - lo)[keep],
        0.0,
        label=WALL,
        instance=0,
        colour=0.0,
        material=ap.PLAIN,
        face_instance=face_inst[keep],
        face_colour=face_col[keep],
        face_mask=mask[keep],
    )
    for space in plan.spaces:
        _add_slabs(plan, space, mb, ids, looks[space.index])


def _wall_boxes(plan: Plan, holes: np.ndarray) -> np.ndarray:
    """Solid wall boxes (k, 6): the outline minus the spaces on the grid of all space edges,
    carved around the openings so reveals, lintels and sills exist."""
    ox0, oy0, ox1, oy1 = plan.outline
    rects = [(s.index, r) for s in plan.spaces for r in s.rects]
    xs = np.unique([ox0, ox1, *[v for _, r in rects for v in (r[0], r[2])]])
    ys = np.unique([oy0, oy1, *[v for _, r in rects for v in (r[1], r[3])]])
    boxes: list[Box3] = []
    for (xa, xb), (ya, yb) in itertools.product(
        zip(xs[:-1], xs[1:], strict=True), zip(ys[:-1], ys[1:], strict=True)
    ):
        cx, cy = 0.5 * (xa + xb), 0.5 * (ya + yb)
        if any(bool(s.contains(cx, cy)) for s in plan.spaces):
            continue
        boxes.extend(_carve((xa, ya, 0.0, xb, yb, plan.height), holes))
    return np.array(boxes)


class _WallPlanes:
    """One instance id and colour per wall plane, so every face of a plane (and the reveals
    painted like it) share them; colours are drawn when a plane is first seen."""

    def __init__(self, ids: Ids, looks: list[SpaceLook], rng: np.random.Generator) -> None:
        self.ids, self.looks, self.rng = ids, looks, rng
        self.plane_ids: dict[tuple[int, int, int, float, int], int] = {}
        self.colour: dict[int, np.ndarray] = {}

    def instance(self, space: int, axis: int, sign: int, coord: float, reveal: int = -1) -> int:
        """The instance of the plane of ``space`` facing ``sign`` along ``axis`` at ``coord``
        (or of the reveal of opening ``reveal`` on it)."""
        key = (space, axis, sign, round(float(coord), 4), reveal)
        if key not in self.plane_ids:
            self.plane_ids[key] = self.ids()
            if reveal >= 0:
                face_key = (space, axis, sign, round(float(coord), 4), -1)
                if face_key in self.plane_ids:
                    self.colour[self.plane_ids[key]] = self.colour[self.plane_ids[face_key]]
                    return self.plane_ids[key]
            base = self.looks[space].wall
            if self.rng.random() < 0.07:  # the odd accent wall
                base = ap.sample_colour(self.rng, "wall") * self.rng.uniform(0.8, 1.0)
            self.colour[self.plane_ids[key]] = base * self.rng.uniform(0.97, 1.03)
        return self.plane_ids[key]


def _wall_faces(
    plan: Plan, lo: np.ndarray, hi: np.ndarray, holes: np.ndarray, planes: _WallPlanes
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which faces of the wall boxes look into a space or an opening, and the instance and
    colour of each: (k, 6) ids, (k, 6, 3) colours and the (k, 6) mask."""
    centre = 0.5 * (lo + hi)
    k = lo.shape[0]
    face_inst = np.zeros((k, 6), dtype=np.int64)
    face_col = np.zeros((k, 6, 3))
    mask = np.zeros((k, 6), dtype=bool)
    for f in range(6):
        axis, sign = f // 2, (1 if f % 2 == 0 else -1)
        plane_coord = (hi if sign > 0 else lo)[:, axis]
        probe = centre.copy()
        probe[:, axis] = plane_coord + sign * 1e-3
        hole_idx, space_idx = _face_targets(plan, probe, holes)
        for i in np.flatnonzero((hole_idx >= 0) | (space_idx >= 0)):
            if hole_idx[i] >= 0:  # a reveal: its own plane, painted like face A
                fa = plan.openings[hole_idx[i]].face
                inst = planes.instance(fa.space, fa.axis, fa.sign, fa.coord, int(hole_idx[i]))
            else:
                inst = planes.instance(int(space_idx[i]), axis, sign, plane_coord[i])
            mask[i, f] = True
            face_inst[i, f] = inst
            face_col[i, f] = planes.colour[inst]
    return face_inst, face_col, mask


def _face_targets(
    plan: Plan, probe: np.ndarray, holes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The opening (else -1) and the space (else -1) each probe point just outside a face lies
    in: a face is seen only from there."""
    k = probe.shape[0]
    hole_idx = np.full(k, -1)
    if holes.shape[0]:
        in_hole = np.all(
            (holes[None, :, :3] < probe[:, None, :]) & (probe[:, None, :] < holes[None, :, 3:]),
            axis=2,
        )
        hole_idx = np.where(in_hole.any(axis=1), np.argmax(in_hole, axis=1), -1)
    z_ok = (probe[:, 2] > 0.0) & (probe[:, 2] < plan.height)
    space_idx = np.full(k, -1)
    for sp in plan.spaces:
        hit = (space_idx < 0) & z_ok & sp.contains(probe[:, 0], probe[:, 1])
        space_idx[hit] = sp.index
    return hole_idx, space_idx


def _add_slabs(plan: Plan, space: Space, mb: MeshBuilder, ids: Ids, look: SpaceLook) -> None:
    """A space's floor and ceiling slabs, and the floor under its doors (one instance each)."""
    h = plan.height
    fl, ce = ids(), ids()
    for x0, y0, x1, y1 in space.rects:
        c = [(x0 + x1) / 2, (y0 + y1) / 2]
        size = [x1 - x0, y1 - y0, SLAB]
        mb.add_boxes(
            [[*c, -SLAB / 2]],
            size,
            label=FLOOR,
            instance=fl,
            colour=look.floor,
            material=look.floor_material,
        )
        mb.add_boxes(
            [[*c, h + SLAB / 2]],
            size,
            label=CEILING,
            instance=ce,
            colour=look.ceiling,
            material=look.ceiling_material,
        )
    for o in plan.openings:
        if o.face.space == space.index and o.kind == "door":
            ob = o.box()
            mb.add_boxes(
                [[(ob[0] + ob[3]) / 2, (ob[1] + ob[4]) / 2, -SLAB / 2]],
                [ob[3] - ob[0], ob[4] - ob[1], SLAB],
                label=FLOOR,
                instance=fl,
                colour=look.floor,
                material=look.floor_material,
            )


def _opening_pose(o: Opening) -> Pose:
    """Pose at the opening's centre on face A: local x along the wall, +y into space A."""
    f = o.face
    p = f.point(0.5 * (o.u0 + o.u1))
    return Pose(float(p[0]), float(p[1]), f.yaw)


def build_door(o: Opening, mb: MeshBuilder, ids: Ids, rng: np.random.Generator) -> None:
    """A door leaf (or two) in its opening, with lining, casings and handles; sometimes open."""
    inst = ids()
    pose = _opening_pose(o)
    w, hd, depth = o.width, o.z1, o.depth
    leaf_col = ap.sample_colour(rng, "door")
    woody = leaf_col[0] > leaf_col[2] + 0.15
    frame_col = (
        leaf_col * rng.uniform(0.85, 1.0) if rng.random() < 0.5 else ap.sample_colour(rng, "frame")
    )
    leaf_mat = ap.WOOD if woody else ap.PLAIN
    attrs = {"label": DOOR, "instance": inst}
    jt = float(rng.uniform(0.02, 0.035))  # lining thickness in the reveal
    cw, cp = float(rng.uniform(0.05, 0.08)), float(rng.uniform(0.03, 0.045))  # casing width, proud
    sides = [1.0] + ([-1.0] if o.face.other is not None else [])
    c, s = _door_frame(w, hd, depth, lining=jt, casing=(cw, cp), sides=sides)
    mb.add_local_boxes(pose, c, s, colour=frame_col, material=ap.PLAIN, **attrs)
    inner = w - 2 * jt - 0.006
    lt = 0.04
    n_leaves = 2 if w > 1.4 else 1
    lw = inner / n_leaves - (0.003 if n_leaves == 2 else 0.0)
    lh = hd - jt - 0.008
    for leaf in range(n_leaves):
        if o.open_angle > 0 and leaf == 0:
            hinge = np.array([-w / 2 + jt + 0.003, 0.0])
            a = o.open_angle
            d = np.array([math.cos(a), math.sin(a)])
            ctr = hinge + d * lw / 2 + np.array([d[1], -d[0]]) * lt / 2
            yaw = a
        else:
            # Leaf plane 3.5-6 cm behind (or proud of) the wall face: a plane of its own.
            recess = float(rng.uniform(0.035, 0.06)) * (1 if rng.random() < 0.7 else -1)
            recess = min(recess, depth - lt - 0.005)
            x0 = -inner / 2 + leaf * (lw + 0.006)
            ctr = np.array([x0 + lw / 2, -recess - lt / 2])
            yaw = 0.0
        mb.add_local_boxes(
            pose,
            [[ctr[0], ctr[1], 0.006 + lh / 2]],
            [lw, lt, lh],
            yaw,
            colour=leaf_col,
            material=leaf_mat,
            **attrs,
        )
        if o.open_angle == 0 or leaf > 0:
            hx = ctr[0] + (lw / 2 - 0.09) * (1 if leaf == n_leaves - 1 else -1)
            hy = [ctr[1] + lt / 2 + 0.03] + ([ctr[1] - lt / 2 - 0.03] if len(sides) > 1 else [])
            hc = [[hx, y, 1.02] for y in hy]
            mb.add_local_boxes(
                pose,
                hc,
                [0.13, 0.03, 0.025],
                colour=ap.sample_colour(rng, "metal"),
                material=ap.METAL,
                **attrs,
            )


def _door_frame(
    w: float,
    hd: float,
    depth: float,
    *,
    lining: float,
    casing: tuple[float, float],
    sides: list[float],
) -> tuple[np.ndarray, np.ndarray]:
    """Centres and sizes of a door's lining (in the reveal) and of its casings on each side
    that faces a space (+1: face A, -1: the other): boxes in the opening's local frame."""
    jt, (cw, cp) = lining, casing
    c = [[-w / 2 + jt / 2, -depth / 2, hd / 2], [w / 2 - jt / 2, -depth / 2, hd / 2]]
    s = [[jt, depth, hd], [jt, depth, hd]]
    c += [[0.0, -depth / 2, hd - jt / 2]]
    s += [[w - 2 * jt, depth, jt]]
    for side in sides:
        y = cp / 2 if side > 0 else -depth - cp / 2
        c += [[-w / 2 - cw / 2, y, hd / 2], [w / 2 + cw / 2, y, hd / 2], [0.0, y, hd + cw / 2]]
        s += [[cw, cp, hd], [cw, cp, hd], [w + 2 * cw, cp, cw]]
    return np.array(c), np.array(s)


def build_window(o: Opening, mb: MeshBuilder, ids: Ids, rng: np.random.Generator) -> None:
    """Glass, frame, mullions, an interior sill and sometimes blinds inside a window opening."""
    inst = ids()
    pose = _opening_pose(o)
    w, z0, z1, depth = o.width, o.z0, o.z1, o.depth
    hgt = z1 - z0
    frame_col = ap.sample_colour(rng, "frame")
    fw, fd = float(rng.uniform(0.04, 0.07)), float(rng.uniform(0.05, 0.08))
    gy = min(-depth * float(rng.uniform(0.45, 0.75)), -0.045 - fd / 2)  # frame behind the face
    attrs = {"label": WINDOW, "instance": inst}
    c = [[-w / 2 + fw / 2, gy, z0 + hgt / 2], [w / 2 - fw / 2, gy, z0 + hgt / 2]]
    s = [[fw, fd, hgt], [fw, fd, hgt]]
    c += [[0.0, gy, z0 + fw / 2], [0.0, gy, z1 - fw / 2]]
    s += [[w - 2 * fw, fd, fw], [w - 2 * fw, fd, fw]]
    n_mull = int((w - 0.2) // 0.9)
    for i in range(n_mull):
        c.append([-w / 2 + w * (i + 1) / (n_mull + 1), gy, z0 + hgt / 2])
        s.append([fw * 0.8, fd, hgt - 2 * fw])
    if hgt > 1.5 and rng.random() < 0.5:
        c.append([0.0, gy, z0 + hgt * 0.7])
        s.append([w - 2 * fw, fd, fw * 0.8])
    mb.add_local_boxes(pose, np.array(c), np.array(s), colour=frame_col, material=ap.METAL, **attrs)
    glass = ap.sample_colour(rng, "glass")
    mb.add_local_boxes(
        pose,
        [[0.0, gy, z0 + hgt / 2]],
        [w - 2 * fw, 0.008, hgt - 2 * fw],
        colour=glass,
        material=ap.GLASS,
        **attrs,
    )
    sill_y0, sill_y1 = gy + fd / 2, float(rng.uniform(0.02, 0.08))
    mb.add_local_boxes(
        pose,
        [[0.0, (sill_y0 + sill_y1) / 2, z0 + 0.0125]],
        [w + 0.1, sill_y1 - sill_y0, 0.025],
        colour=frame_col * 0.97,
        material=ap.PLAIN,
        **attrs,
    )
    if rng.random() < 0.3:  # a roller blind mounted in front of the opening
        bh = hgt * float(rng.uniform(0.3, 0.95))
        by = float(rng.uniform(0.05, 0.08))
        mb.add_local_boxes(
            pose,
            [[0.0, by, z1 - bh / 2], [0.0, by, z1 + 0.04]],
            [[w + 0.1, 0.012, bh], [w + 0.14, 0.08, 0.08]],
            colour=ap.sample_colour(rng, "blind"),
            material=ap.FABRIC,
            **attrs,
        )


def build_openings(plan: Plan, mb: MeshBuilder, ids: Ids, rng: np.random.Generator) -> None:
    """Fill every opening of the plan with its door or window."""
    for o in plan.openings:
        if o.kind == "door":
            build_door(o, mb, ids, rng)
        else:
            build_window(o, mb, ids, rng)
