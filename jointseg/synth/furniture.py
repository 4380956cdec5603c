"""Tables, chairs, sofas and bookcases built from boxes and prisms at real-world sizes.

Each ``make_*`` draws the random parameters of one piece (size, style, colours) and returns an
:class:`Item` whose footprint is known before it is placed, so the placement code can test for
free space first and build the mesh only once a pose is accepted. Local frame: footprint
centred on the origin, +y is the front (a chair faces +y, a bookcase opens to +y).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from jointseg.classes import CLASS_INDEX
from jointseg.synth import appearance as ap
from jointseg.synth.layout import Box3
from jointseg.synth.meshes import MeshBuilder, Pose
from jointseg.synth.structure import Ids

TABLE, CHAIR, SOFA = CLASS_INDEX["table"], CLASS_INDEX["chair"], CLASS_INDEX["sofa"]
BOOKCASE = CLASS_INDEX["bookcase"]


@dataclass(frozen=True)
class Surface:
    """A horizontal rectangle (a table top) that can carry small items."""

    pose: Pose
    w: float
    d: float
    z: float


Builder = Callable[[MeshBuilder, Pose, Ids], "Surface | None"]


@dataclass
class Item:
    """A sampled object: local footprint ``w`` x ``d``, height ``h`` and its mesh builder."""

    kind: str
    w: float
    d: float
    h: float
    build: Builder

    def aabb(self, pose: Pose) -> Box3:
        """Scene bounding box of the item at ``pose``."""
        return pose.aabb(-self.w / 2, -self.d / 2, self.w / 2, self.d / 2, 0.0, self.h)


def _legs(w: float, d: float, inset: float, size: float, h: float) -> tuple[list, list]:
    """Centres and sizes of four square legs under a w x d top, reaching height h."""
    xs, ys = w / 2 - inset - size / 2, d / 2 - inset - size / 2
    c = [[sx * xs, sy * ys, h / 2] for sx in (-1, 1) for sy in (-1, 1)]
    return c, [[size, size, h]] * 4


def make_table(rng: np.random.Generator, style: str = "desk") -> Item:
    """A desk, conference, round, coffee or training table."""
    if style == "conference":
        w, d, h = rng.uniform(2.4, 4.8), rng.uniform(1.0, 1.4), rng.uniform(0.72, 0.76)
    elif style == "round":
        w = d = rng.uniform(0.7, 1.1)
        h = rng.uniform(0.70, 0.76)
    elif style == "coffee":
        w, d, h = rng.uniform(0.8, 1.2), rng.uniform(0.5, 0.7), rng.uniform(0.4, 0.5)
    elif style == "training":
        w, d, h = rng.uniform(1.2, 1.6), rng.uniform(0.5, 0.65), rng.uniform(0.72, 0.76)
    else:
        w, d, h = rng.uniform(1.2, 1.8), rng.uniform(0.6, 0.8), rng.uniform(0.72, 0.76)
    w, d, h = float(w), float(d), float(h)
    top_col = ap.sample_colour(rng, "desk")
    top_mat = ap.WOOD if top_col[0] > top_col[2] + 0.12 else ap.PLAIN
    leg_col = ap.sample_colour(rng, "metal")
    tt = float(rng.uniform(0.025, 0.04))
    panels = style in ("desk", "training") and rng.random() < 0.45
    leg = float(rng.uniform(0.04, 0.06))

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> Surface:
        inst = ids()
        attrs = {"label": TABLE, "instance": inst}
        if style == "round":
            bottom = pose.world([[0.0, 0.0, h - tt]])
            mb.add_prisms(bottom, w / 2, tt, sides=20, colour=top_col, material=top_mat, **attrs)
            base = pose.world([[0.0, 0.0, 0.0]])
            mb.add_prisms(base, 0.035, h - tt, sides=8, colour=leg_col, material=ap.METAL, **attrs)
            mb.add_prisms(base, 0.26, 0.025, sides=12, colour=leg_col, material=ap.METAL, **attrs)
            return Surface(pose, w * 0.68, d * 0.68, h)
        mb.add_local_boxes(
            pose, [[0.0, 0.0, h - tt / 2]], [w, d, tt], colour=top_col, material=top_mat, **attrs
        )
        if panels:
            c = [[-w / 2 + 0.03, 0.0, (h - tt) / 2], [w / 2 - 0.03, 0.0, (h - tt) / 2]]
            s = [[0.025, d - 0.04, h - tt]] * 2
            c.append([0.0, -d / 2 + 0.05, h - tt - 0.2])
            s.append([w - 0.09, 0.018, 0.4])
            mb.add_local_boxes(pose, c, s, colour=top_col * 0.95, material=top_mat, **attrs)
        elif style == "conference" and w > 3.0:
            c = [[sx * w / 4, 0.0, (h - tt) / 2] for sx in (-1, 1)]
            mb.add_local_boxes(
                pose, c, [[0.35, d * 0.45, h - tt]] * 2, colour=leg_col, material=ap.METAL, **attrs
            )
        else:
            c, s = _legs(w, d, 0.04, leg, h - tt)
            mb.add_local_boxes(pose, c, s, colour=leg_col, material=ap.METAL, **attrs)
        return Surface(pose, w, d, h)

    return Item("table", w, d, h, build)


def make_chair(rng: np.random.Generator, style: str | None = None) -> Item:
    """An office swivel chair or a four-legged chair (front = +y)."""
    style = style or ("office" if rng.random() < 0.6 else "legs")
    col = ap.sample_colour(rng, "chair")
    frame = ap.sample_colour(rng, "metal")
    mat = ap.FABRIC if rng.random() < 0.6 else ap.PLAIN
    if style == "office":
        sw, sd, sh = rng.uniform(0.47, 0.55), rng.uniform(0.45, 0.52), rng.uniform(0.44, 0.5)
        bh = float(rng.uniform(0.45, 0.72))
        arms = rng.random() < 0.5
        w = d = 0.62
    else:
        sw, sd, sh = rng.uniform(0.40, 0.47), rng.uniform(0.40, 0.46), rng.uniform(0.44, 0.47)
        bh = float(rng.uniform(0.35, 0.45))
        arms = False
        w, d = float(sw) + 0.02, float(sd) + 0.04
    sw, sd, sh = float(sw), float(sd), float(sh)
    h = sh + 0.05 + bh

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        attrs = {"label": CHAIR, "instance": ids()}
        st = 0.07 if style == "office" else 0.04
        c = [[0.0, 0.0, sh - st / 2], [0.0, -sd / 2 + 0.03, sh + 0.05 + bh / 2]]
        s = [[sw, sd, st], [sw * 0.95, 0.05, bh]]
        mb.add_local_boxes(pose, c, s, colour=col, material=mat, **attrs)
        if style == "office":
            spine = [[0.0, -sd / 2 + 0.03, sh + 0.03]]
            mb.add_local_boxes(pose, spine, [0.06, 0.04, 0.1], colour=frame, **attrs)
            mb.add_prisms(
                pose.world([[0.0, 0.0, 0.08]]),
                0.025,
                sh - st - 0.08,
                sides=8,
                colour=frame,
                material=ap.METAL,
                **attrs,
            )
            yaws = pose.yaw + np.arange(5) * 2 * np.pi / 5
            ctr = np.stack([np.cos(yaws) * 0.14, np.sin(yaws) * 0.14, np.full(5, 0.06)], 1)
            ctr[:, :2] += [pose.x, pose.y]
            mb.add_boxes(ctr, [0.28, 0.04, 0.04], yaws, colour=frame, material=ap.METAL, **attrs)
            if arms:
                ac = [[sx * (sw / 2 - 0.02), 0.0, sh + 0.1] for sx in (-1, 1)]
                mb.add_local_boxes(pose, ac, [[0.04, 0.06, 0.2]] * 2, colour=frame, **attrs)
                ap_ = [[sx * (sw / 2 - 0.02), 0.0, sh + 0.215] for sx in (-1, 1)]
                mb.add_local_boxes(pose, ap_, [[0.06, 0.25, 0.03]] * 2, colour=col * 0.6, **attrs)
        else:
            lc, ls = _legs(sw, sd, 0.01, 0.03, sh - st)
            mb.add_local_boxes(pose, lc, ls, colour=frame, material=ap.METAL, **attrs)
            posts = [[sx * (sw / 2 - 0.025), -sd / 2 + 0.03, sh + 0.025] for sx in (-1, 1)]
            mb.add_local_boxes(pose, posts, [[0.03, 0.03, 0.05]] * 2, colour=frame, **attrs)

    return Item("chair", w, d, h, build)


def make_sofa(rng: np.random.Generator, armchair: bool | None = None) -> Item:
    """A two-/three-seater sofa or an armchair with cushions, back and arms (front = +y)."""
    if armchair is None:
        armchair = bool(rng.random() < 0.3)
    w = float(rng.uniform(0.8, 1.0) if armchair else rng.uniform(1.5, 2.4))
    d, sh = float(rng.uniform(0.8, 0.95)), float(rng.uniform(0.40, 0.45))
    h, ah, bd = float(rng.uniform(0.75, 0.92)), float(rng.uniform(0.55, 0.65)), 0.2
    aw = float(rng.uniform(0.14, 0.24))
    col = ap.sample_colour(rng, "sofa")
    n_cush = 1 if armchair else int(np.clip(round((w - 2 * aw) / 0.65), 2, 3))

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        attrs = {"label": SOFA, "instance": ids(), "material": ap.FABRIC}
        c = [[0.0, 0.0, 0.08 + (sh - 0.2) / 2], [0.0, -d / 2 + bd / 2, 0.08 + (h - 0.08) / 2]]
        s = [[w, d, sh - 0.2], [w, bd, h - 0.08]]
        c += [[sx * (w / 2 - aw / 2), bd / 2, 0.08 + (ah - 0.08) / 2] for sx in (-1, 1)]
        s += [[aw, d - bd, ah - 0.08]] * 2
        mb.add_local_boxes(pose, c, s, colour=col, **attrs)
        inner = w - 2 * aw
        cw = inner / n_cush
        cc = [[-inner / 2 + cw * (i + 0.5), bd / 2 + 0.01, sh - 0.06] for i in range(n_cush)]
        mb.add_local_boxes(
            pose, cc, [[cw - 0.015, d - bd - 0.02, 0.12]] * n_cush, colour=col * 1.05, **attrs
        )
        fc, fs = _legs(w, d, 0.04, 0.05, 0.08)
        mb.add_local_boxes(pose, fc, fs, colour=col * 0.4, **attrs)

    return Item("sofa", w, d, h, build)


def make_bookcase(rng: np.random.Generator, low: bool = False) -> Item:
    """A shelf unit filled with books (books are labelled bookcase, as in S3DIS)."""
    w = float(rng.uniform(0.75, 1.2))
    d = float(rng.uniform(0.28, 0.4))
    h = float(rng.uniform(0.8, 1.25) if low else rng.uniform(1.75, 2.25))
    pt = float(rng.uniform(0.018, 0.028))
    n_shelves = max(2, round((h - 0.1) / rng.uniform(0.3, 0.4)))
    col = ap.sample_colour(rng, "bookcase")
    mat = ap.WOOD if col[0] > col[2] + 0.12 else ap.PLAIN
    fill = rng.uniform(0.3, 1.0, n_shelves)

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        attrs = {"label": BOOKCASE, "instance": ids()}
        c = [[-w / 2 + pt / 2, 0.0, h / 2], [w / 2 - pt / 2, 0.0, h / 2], [0.0, 0.0, h - pt / 2]]
        s = [[pt, d, h], [pt, d, h], [w - 2 * pt, d, pt]]
        c += [[0.0, -d / 2 + 0.005, h / 2], [0.0, 0.0, 0.04]]
        s += [[w - 2 * pt, 0.01, h - pt], [w - 2 * pt, d, 0.08]]
        gap = (h - 0.08 - pt) / n_shelves
        levels = 0.08 + gap * np.arange(n_shelves)
        for z in levels[1:]:
            c.append([0.0, 0.005, z - pt / 2])
            s.append([w - 2 * pt, d - 0.01, pt])
        mb.add_local_boxes(pose, c, s, colour=col, material=mat, **attrs)
        inner = w - 2 * pt
        bc, bs = [], []
        for z, f in zip(levels, fill, strict=True):
            widths = rng.uniform(0.018, 0.06, int(inner / 0.018) + 1)
            ends = np.cumsum(widths + 0.002)
            keep = ends < inner * f - 0.006
            if not keep.any():
                continue
            widths, ends = widths[keep], ends[keep]
            start = -inner / 2 + 0.003 + (rng.uniform(0, inner * (1 - f)) if f < 0.9 else 0.0)
            x = start + ends - widths / 2
            hh = rng.uniform(0.55, 0.9, x.size) * (gap - pt)
            dd = rng.uniform(0.6, 0.92, x.size) * (d - 0.02)
            bc.append(np.stack([x, -d / 2 + 0.012 + dd / 2, z + hh / 2], 1))
            bs.append(np.stack([widths, dd, hh], 1))
        if bc:
            centres, sizes = np.concatenate(bc), np.concatenate(bs)
            colours = ap.sample_colour(rng, "book", centres.shape[0])
            mb.add_local_boxes(pose, centres, sizes, colour=colours, material=ap.PLAIN, **attrs)

    return Item("bookcase", w, d, h, build)
