"""Built-in elements of a room: beams, columns, ceiling lamps, boards and radiators.

They are placed before the furniture because they constrain it (a column in a corner, a board
needing free wall, a radiator under a window) and because the lamps double as the light sources
for shading.
"""

from __future__ import annotations

import numpy as np

from jointseg.classes import CLASS_INDEX
from jointseg.synth import appearance as ap
from jointseg.synth.layout import Occupancy, Plan, Space, WallFace
from jointseg.synth.meshes import MeshBuilder, Pose
from jointseg.synth.structure import Ids, SpaceLook

BEAM, COLUMN = CLASS_INDEX["beam"], CLASS_INDEX["column"]
BOARD, CLUTTER = CLASS_INDEX["board"], CLASS_INDEX["clutter"]
CEILING = CLASS_INDEX["ceiling"]


def _full_wall(space: Space, axis: int, sign: int, coord: float, a: float, b: float) -> bool:
    """Whether a wall face of ``space`` covers [a, b] on the plane ``axis = coord``."""
    return any(
        f.axis == axis
        and f.sign == sign
        and abs(f.coord - coord) < 1e-9
        and f.u0 <= a
        and f.u1 >= b
        for f in space.faces
    )


def add_beams(
    space: Space,
    plan: Plan,
    mb: MeshBuilder,
    ids: Ids,
    rng: np.random.Generator,
    occ: Occupancy,
    look: SpaceLook,
) -> int:
    """Ceiling beams spanning the space wall to wall; returns how many were built."""
    h = plan.height
    rect = max(space.rects, key=lambda r: (r[2] - r[0]) * (r[3] - r[1]))
    x0, y0, x1, y1 = rect
    axes = [0, 1]
    rng.shuffle(axes)
    col = look.ceiling * rng.uniform(0.93, 1.0) if rng.random() < 0.6 else look.wall * 0.97
    door_top = max([o.z1 for o in plan.openings if o.kind == "door"], default=2.1)
    depth = float(rng.uniform(0.25, 0.6))
    depth = max(0.15, min(depth, h - door_top - 0.3, h - 2.25))
    width = float(rng.uniform(0.25, 0.45))
    built = 0
    for span_axis in axes:
        lo, hi = (y0, y1) if span_axis == 0 else (x0, x1)
        n = int(np.clip(round((hi - lo) / rng.uniform(2.5, 4.5)) - 1, 1, 3))
        pos = lo + (hi - lo) * (np.arange(1, n + 1) / (n + 1)) + rng.uniform(-0.3, 0.3, n)
        for p in pos:
            a, b = p - width / 2, p + width / 2
            if span_axis == 0:
                ok = _full_wall(space, 0, 1, x0, a, b) and _full_wall(space, 0, -1, x1, a, b)
                box = (x0, a, h - depth, x1, b, h)
            else:
                ok = _full_wall(space, 1, 1, y0, a, b) and _full_wall(space, 1, -1, y1, a, b)
                box = (a, y0, h - depth, b, y1, h)
            if not ok or not occ.fits(box, margin=0.0):
                continue
            lo3, hi3 = np.array(box[:3]), np.array(box[3:])
            mb.add_boxes(
                [(lo3 + hi3) / 2],
                hi3 - lo3,
                label=BEAM,
                instance=ids(),
                colour=col,
                material=ap.PLAIN,
            )
            occ.add(box)
            built += 1
        if built:
            break
    return built


def _wall_pose(face: WallFace, u: float, offset: float, z: float = 0.0) -> Pose:
    """Pose backed onto ``face`` at ``u``, ``offset`` m into the room, base at height ``z``."""
    p = face.point(u, offset)
    return Pose(float(p[0]), float(p[1]), face.yaw, z)


def pick_face(space: Space, rng: np.random.Generator, min_len: float) -> WallFace | None:
    """A random wall face at least ``min_len`` long, longer faces more likely."""
    faces = [f for f in space.faces if f.length >= min_len]
    if not faces:
        return None
    w = np.array([f.length for f in faces])
    return faces[int(rng.choice(len(faces), p=w / w.sum()))]


def add_columns(
    space: Space,
    plan: Plan,
    mb: MeshBuilder,
    ids: Ids,
    rng: np.random.Generator,
    occ: Occupancy,
    look: SpaceLook,
    count: int,
) -> int:
    """Box columns in corners, against walls or (in big rooms) free-standing."""
    h, built = plan.height, 0
    # Painted like the walls, or clad / painted in a contrasting shade.
    col = (
        look.wall * rng.uniform(0.92, 1.02)
        if rng.random() < 0.4
        else ap.sample_colour(rng, "column")
    )
    for _ in range(count * 15):
        if built >= count:
            break
        a, b = float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.2, 0.5))
        x0, y0, x1, y1 = space.bbox
        if min(x1 - x0, y1 - y0) > 4.0 and space.area > 40 and rng.random() < 0.2:
            pose = Pose(
                float(rng.uniform(x0 + 1.5, x1 - 1.5)), float(rng.uniform(y0 + 1.5, y1 - 1.5))
            )
            a = b = max(a, b)
        else:
            face = pick_face(space, rng, a + 0.1)
            if face is None:
                return built
            r = rng.random()
            u = face.u0 + a / 2 if r < 0.3 else face.u1 - a / 2 if r < 0.6 else None
            if u is None:
                u = float(rng.uniform(face.u0 + a / 2, face.u1 - a / 2))
            pose = _wall_pose(face, u, b / 2)
        box = pose.aabb(-a / 2, -b / 2, a / 2, b / 2, 0.0, h)
        if not space.contains(pose.x, pose.y) or not occ.fits(box, margin=0.0):
            continue
        mb.add_local_boxes(
            pose,
            [[0.0, 0.0, h / 2]],
            [a, b, h],
            label=COLUMN,
            instance=ids(),
            colour=col,
            material=ap.PLAIN,
        )
        occ.add(box)
        built += 1
    return built


def add_lamps(
    space: Space,
    plan: Plan,
    mb: MeshBuilder,
    ids: Ids,
    rng: np.random.Generator,
    occ: Occupancy,
) -> list[tuple[float, float, float]]:
    """Ceiling lamps on a grid; returns light positions for shading.

    Flush panels and strips are labelled ceiling (as S3DIS does for fittings in the ceiling),
    pendants clutter.
    """
    h = plan.height
    style = rng.choice(["square", "strip", "pendant"], p=[0.55, 0.3, 0.15])
    size = {"square": (0.6, 0.6), "strip": (1.2, 0.25), "pendant": (0.4, 0.4)}[str(style)]
    thick = (
        float(rng.uniform(0.04, 0.08)) if style == "pendant" else float(rng.uniform(0.015, 0.04))
    )
    drop = float(rng.uniform(0.3, 0.7)) if style == "pendant" else 0.0
    spacing = float(rng.uniform(2.2, 3.2))
    col = ap.sample_colour(rng, "lamp")
    lights: list[tuple[float, float, float]] = []
    for x0, y0, x1, y1 in space.rects:
        nx, ny = max(1, round((x1 - x0) / spacing)), max(1, round((y1 - y0) / spacing))
        for i in range(nx):
            for j in range(ny):
                cx, cy = x0 + (x1 - x0) * (i + 0.5) / nx, y0 + (y1 - y0) * (j + 0.5) / ny
                zb = h - drop - thick
                box = (
                    cx - size[0] / 2,
                    cy - size[1] / 2,
                    zb,
                    cx + size[0] / 2,
                    cy + size[1] / 2,
                    h,
                )
                if not occ.fits(box, margin=0.05):
                    continue
                lights.append((cx, cy, zb - 0.03))
                inst = ids()
                mb.add_boxes(
                    [[cx, cy, zb + thick / 2]],
                    [size[0], size[1], thick],
                    label=CLUTTER if style == "pendant" else CEILING,  # flush fittings: ceiling
                    instance=inst,
                    colour=col,
                    material=ap.LAMP,
                )
                if style == "pendant":
                    mb.add_prisms(
                        [[cx, cy, zb + thick]],
                        0.006,
                        drop,
                        sides=4,
                        label=CLUTTER,
                        instance=inst,
                        colour=col * 0.3,
                    )
                occ.add(box)
    if not lights:  # every lamp position was taken (beams): light from the centre
        x0, y0, x1, y1 = space.bbox
        lights.append(((x0 + x1) / 2, (y0 + y1) / 2, h - 0.3))
    return lights


def add_board(
    space: Space,
    plan: Plan,
    mb: MeshBuilder,
    ids: Ids,
    rng: np.random.Generator,
    occ: Occupancy,
    faces: list[WallFace] | None = None,
) -> bool:
    """A whiteboard or blackboard a few cm off a free stretch of wall, with frame and tray."""
    dark = rng.random() < 0.25
    col = ap.sample_colour(rng, "blackboard" if dark else "whiteboard")
    frame = ap.sample_colour(rng, "metal")
    for _ in range(40):
        w = float(rng.uniform(0.9, 2.0))
        face = faces[int(rng.integers(len(faces)))] if faces else pick_face(space, rng, 1.4)
        if face is None:
            return False
        w = min(w, face.length - 0.3)
        if w < 0.9:
            continue
        hb, zb = float(rng.uniform(0.6, 1.0)), float(rng.uniform(0.85, 1.05))
        gap, th = float(rng.uniform(0.025, 0.045)), float(rng.uniform(0.012, 0.02))
        u = float(rng.uniform(face.u0 + w / 2 + 0.1, face.u1 - w / 2 - 0.1))
        pose = _wall_pose(face, u, 0.0, zb)
        clear = pose.aabb(-w / 2, 0.0, w / 2, 0.45, -zb, hb + 0.03)  # free floor in front
        if not occ.fits(clear, margin=0.05):
            continue
        attrs = {"label": BOARD, "instance": ids()}
        y = gap + th / 2
        mb.add_local_boxes(
            pose, [[0.0, y, hb / 2]], [w, th, hb], colour=col, material=ap.PLAIN, **attrs
        )
        fy, fs = gap + th / 2 + 0.004, 0.025
        c = [[-w / 2 - fs / 2, fy, hb / 2], [w / 2 + fs / 2, fy, hb / 2]]
        s = [[fs, th + 0.008, hb + 2 * fs]] * 2
        c += [[0.0, fy, hb + fs / 2], [0.0, fy, -fs / 2], [0.0, gap + 0.04, -fs - 0.01]]
        s += [[w, th + 0.008, fs], [w, th + 0.008, fs], [w * 0.8, 0.06, 0.02]]
        mb.add_local_boxes(pose, c, s, colour=frame, material=ap.METAL, **attrs)
        occ.add(pose.aabb(-w / 2 - fs, 0.0, w / 2 + fs, gap + th + 0.07, -0.15, hb + fs + 0.1))
        occ.add(clear, solid=False)
        return True
    return False


def add_radiators(
    space: Space,
    plan: Plan,
    mb: MeshBuilder,
    ids: Ids,
    rng: np.random.Generator,
    occ: Occupancy,
) -> None:
    """Radiators (clutter) below some windows of the space."""
    col = ap.sample_colour(rng, "paper") * rng.uniform(0.9, 1.0)
    for o in plan.openings:
        if o.kind != "window" or o.face.space != space.index or rng.random() < 0.4:
            continue
        zb = float(rng.uniform(0.1, 0.15))
        hh = float(min(rng.uniform(0.4, 0.6), o.z0 - 0.1 - zb))
        w = float(min(o.width, rng.uniform(0.6, 1.6)))
        d = float(rng.uniform(0.08, 0.12))
        gap = float(rng.uniform(0.03, 0.05))
        if hh < 0.2:
            continue
        pose = _wall_pose(o.face, 0.5 * (o.u0 + o.u1), gap + d / 2, zb)
        box = pose.aabb(-w / 2, -d / 2, w / 2, d / 2, 0.0, hh)
        if not occ.fits(box, margin=0.03):
            continue
        n = max(3, int(w / 0.06))
        xs = -w / 2 + w * (np.arange(n) + 0.5) / n
        c = np.stack([xs, np.zeros(n), np.full(n, hh / 2)], 1)
        mb.add_local_boxes(
            pose,
            c,
            np.tile([w / n * 0.7, d, hh], (n, 1)),
            label=CLUTTER,
            instance=ids(),
            colour=col,
            material=ap.METAL,
        )
        occ.add(box)
