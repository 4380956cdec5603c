"""Clutter, the S3DIS catch-all: cabinets, boxes, bins, plants, monitors, papers, pictures.

Clutter is about an eighth of all S3DIS points and sits everywhere (on the floor, on tables, on
walls), so the generator needs many kinds of small and medium objects with varied shapes and
colours. Builders follow :mod:`jointseg.synth.furniture`: draw parameters first, build later.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from jointseg.classes import CLASS_INDEX
from jointseg.synth import appearance as ap
from jointseg.synth.furniture import Item, Surface
from jointseg.synth.meshes import MeshBuilder, Pose
from jointseg.synth.structure import Ids

CLUTTER = CLASS_INDEX["clutter"]


def make_cabinet(rng: np.random.Generator) -> Item:
    """A filing cabinet, cupboard, sideboard or locker with door/drawer fronts (front = +y)."""
    style = rng.choice(["filing", "cupboard", "sideboard", "locker"], p=[0.35, 0.3, 0.2, 0.15])
    if style == "filing":
        w, d, h, n = rng.uniform(0.4, 0.5), rng.uniform(0.55, 0.65), rng.uniform(0.7, 1.35), 0
    elif style == "cupboard":
        w, d, h, n = rng.uniform(0.8, 1.0), rng.uniform(0.4, 0.5), rng.uniform(1.8, 2.0), 2
    elif style == "sideboard":
        w, d, h, n = rng.uniform(1.2, 1.8), rng.uniform(0.42, 0.5), rng.uniform(0.72, 0.9), 3
    else:
        w, d, h, n = rng.uniform(0.6, 0.9), rng.uniform(0.45, 0.5), rng.uniform(1.7, 1.9), 2
    w, d, h = float(w), float(d), float(h)
    col = ap.sample_colour(rng, "cabinet")
    mat = ap.WOOD if col[0] > col[2] + 0.12 else ap.METAL
    n_drawers = max(2, round(h / 0.33))

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> Surface | None:
        attrs = {"label": CLUTTER, "instance": ids(), "material": mat}
        mb.add_local_boxes(pose, [[0.0, -0.01, h / 2]], [w, d - 0.02, h], colour=col, **attrs)
        if n == 0:
            dh = (h - 0.04) / n_drawers
            zc = 0.02 + dh * (np.arange(n_drawers) + 0.5)
            c = np.stack([np.zeros(n_drawers), np.full(n_drawers, d / 2 - 0.01), zc], 1)
            s = np.tile([w - 0.03, 0.02, dh - 0.012], (n_drawers, 1))
            hc = c + [0.0, 0.02, dh * 0.3]
            hs = np.tile([0.12, 0.02, 0.02], (n_drawers, 1))
        else:
            dw = (w - 0.02) / n
            xc = -w / 2 + 0.01 + dw * (np.arange(n) + 0.5)
            c = np.stack([xc, np.full(n, d / 2 - 0.01), np.full(n, h / 2)], 1)
            s = np.tile([dw - 0.008, 0.02, h - 0.04], (n, 1))
            side = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
            hc = c + np.stack([side * (dw / 2 - 0.06), np.full(n, 0.02), np.zeros(n)], 1)
            hc[:, 2] = min(1.0, h * 0.6)
            hs = np.tile([0.02, 0.02, 0.14], (n, 1))
        mb.add_local_boxes(pose, c, s, colour=col * 0.97, **attrs)
        mb.add_local_boxes(pose, hc, hs, colour=ap.sample_colour(rng, "metal"), **attrs)
        return Surface(pose, w, d - 0.02, h) if h < 1.4 else None  # things get put on it

    return Item("cabinet", w, d, h, build)


def make_floor_item(rng: np.random.Generator) -> Item:
    """A box stack, bin, plant, printer, floor lamp, fridge or bag standing on the floor."""
    kind = str(
        rng.choice(
            ["boxes", "bin", "plant", "printer", "lamp", "fridge", "bag"],
            p=[0.3, 0.2, 0.18, 0.1, 0.07, 0.07, 0.08],
        )
    )
    return _FLOOR_ITEMS[kind](rng)


def _box_stack(rng: np.random.Generator) -> Item:
    """One to three cardboard boxes stacked, largest footprint at the bottom."""
    n = int(rng.integers(1, 4))
    sizes = np.stack(
        [rng.uniform(0.3, 0.6, n), rng.uniform(0.25, 0.5, n), rng.uniform(0.2, 0.45, n)], 1
    )
    sizes = sizes[np.argsort(-sizes[:, 0] * sizes[:, 1])]
    offs = rng.uniform(-0.04, 0.04, (n, 2))
    offs[0] = 0.0
    cols = ap.sample_colour(rng, "cardboard", n)
    w, d, h = float(sizes[0, 0]) + 0.1, float(sizes[0, 1]) + 0.1, float(sizes[:, 2].sum())

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        z = 0.0
        for i in range(sizes.shape[0]):
            c = [[offs[i, 0], offs[i, 1], z + sizes[i, 2] / 2]]
            mb.add_local_boxes(
                pose, c, sizes[i], label=CLUTTER, instance=ids(), colour=cols[i], material=ap.PLAIN
            )
            z += sizes[i, 2]

    return Item("boxes", w, d, h, build)


def _bin(rng: np.random.Generator) -> Item:
    """A round waste bin, wider at the top."""
    r, h = float(rng.uniform(0.13, 0.2)), float(rng.uniform(0.3, 0.5))
    col = ap.sample_colour(rng, "any")

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        base = pose.world([[0.0, 0.0, 0.0]])
        mb.add_prisms(base, r * 0.85, h, top_radii=r, sides=12, colour=col, **_clutter(ids))

    return Item("bin", 2 * r, 2 * r, h, build)


def _plant(rng: np.random.Generator) -> Item:
    """A pot with a leafy blob, on a stem for the taller ones."""
    pr, ph = float(rng.uniform(0.12, 0.2)), float(rng.uniform(0.2, 0.4))
    fr = float(rng.uniform(0.25, 0.45))
    stem = float(rng.uniform(0.0, 0.8))
    pot_col, leaf_col = ap.sample_colour(rng, "pot"), ap.sample_colour(rng, "plant")

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        attrs = _clutter(ids)
        base = pose.world([[0.0, 0.0, 0.0]])
        mb.add_prisms(base, pr * 0.8, ph, top_radii=pr, sides=12, colour=pot_col, **attrs)
        if stem > 0:
            top = base + [0, 0, ph]
            mb.add_prisms(top, 0.02, stem + fr * 0.5, sides=6, colour=leaf_col * 0.6, **attrs)
        centre = base[0] + [0.0, 0.0, ph + stem + fr]
        shape = [fr, fr, fr * 1.1]
        mb.add_blob(centre, shape, rng, roughness=0.3, colour=leaf_col, material=ap.FABRIC, **attrs)

    return Item("plant", 2 * fr * 1.2, 2 * fr * 1.2, ph + stem + 2 * fr, build)


def _printer(rng: np.random.Generator) -> Item:
    """A printer or copier, on a stand half the time."""
    w, d = float(rng.uniform(0.45, 0.65)), float(rng.uniform(0.4, 0.55))
    ph = float(rng.uniform(0.3, 0.5))
    stand = float(rng.uniform(0.0, 0.7)) if rng.random() < 0.5 else 0.0
    col = ap.sample_colour(rng, "cabinet")

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        attrs = _clutter(ids)
        if stand > 0:
            stand_col = ap.sample_colour(rng, "cabinet")
            mb.add_local_boxes(
                pose, [[0.0, 0.0, stand / 2]], [w, d, stand], colour=stand_col, **attrs
            )
        mb.add_local_boxes(
            pose, [[0.0, 0.0, stand + ph / 2]], [w * 0.95, d * 0.95, ph], colour=col, **attrs
        )

    return Item("printer", w, d, stand + ph, build)


def _floor_lamp(rng: np.random.Generator) -> Item:
    """A floor lamp: round foot, thin pole, shade."""
    h = float(rng.uniform(1.5, 1.85))
    col = ap.sample_colour(rng, "metal")

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        attrs = _clutter(ids)
        base = pose.world([[0.0, 0.0, 0.0]])
        mb.add_prisms(base, 0.18, 0.03, sides=12, colour=col, material=ap.METAL, **attrs)
        mb.add_prisms(base, 0.015, h - 0.3, sides=6, colour=col, material=ap.METAL, **attrs)
        shade = ap.sample_colour(rng, "lamp") * 0.95
        top = base + [0, 0, h - 0.3]
        mb.add_prisms(top, 0.12, 0.3, top_radii=0.2, sides=12, colour=shade, **attrs)

    return Item("lamp", 0.45, 0.45, h, build)


def _fridge(rng: np.random.Generator) -> Item:
    """A small fridge or similar box appliance."""
    w, d = float(rng.uniform(0.35, 0.6)), float(rng.uniform(0.35, 0.6))
    h = float(rng.uniform(0.85, 1.6))
    col = ap.sample_colour(rng, "paper")

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        mb.add_local_boxes(pose, [[0.0, 0.0, h / 2]], [w, d, h], colour=col, **_clutter(ids))

    return Item("fridge", w, d, h, build)


def _bag(rng: np.random.Generator) -> Item:
    """A soft bag or backpack: a rough fabric blob."""
    w, d = float(rng.uniform(0.3, 0.5)), float(rng.uniform(0.2, 0.35))
    h = float(rng.uniform(0.25, 0.45))
    col = ap.sample_colour(rng, "any")

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        centre = pose.world([[0.0, 0.0, 0.0]])[0] + [0.0, 0.0, h / 2]
        mb.add_blob(
            centre,
            [w / 2, d / 2, h / 2],
            rng,
            roughness=0.12,
            colour=col,
            material=ap.FABRIC,
            **_clutter(ids),
        )

    return Item("bag", w, d, h, build)


def _clutter(ids: Ids) -> dict[str, int]:
    """Mesh attributes of one new clutter object (a fresh instance id)."""
    return {"label": CLUTTER, "instance": ids()}


#: Floor item builders by kind; each draws its parameters in a fixed order (reproducible rooms).
_FLOOR_ITEMS: dict[str, Callable[[np.random.Generator], Item]] = {
    "boxes": _box_stack,
    "bin": _bin,
    "plant": _plant,
    "printer": _printer,
    "lamp": _floor_lamp,
    "fridge": _fridge,
    "bag": _bag,
}


def make_table_item(rng: np.random.Generator) -> Item:
    """A monitor, keyboard, laptop, paper stack, mug, bottle, book pile or phone for a table."""
    kind = str(
        rng.choice(
            ["monitor", "keyboard", "laptop", "papers", "mug", "bottle", "books", "phone"],
            p=[0.3, 0.12, 0.1, 0.16, 0.08, 0.06, 0.12, 0.06],
        )
    )
    col = ap.sample_colour(rng, "any")
    if kind == "monitor":
        sw, sh = float(rng.uniform(0.48, 0.7)), float(rng.uniform(0.3, 0.42))
        lift = float(rng.uniform(0.08, 0.15))
        w, d, h = sw, 0.22, lift + sh
    elif kind == "keyboard":
        w, d, h = 0.44, 0.15, 0.03
    elif kind == "laptop":
        w, d, h = 0.34, 0.25, 0.23
    elif kind == "papers":
        w, d, h = 0.22, 0.30, float(rng.uniform(0.005, 0.06))
        col = ap.sample_colour(rng, "paper")
    elif kind == "mug":
        w = d = 0.09
        h = 0.1
    elif kind == "bottle":
        w = d = 0.08
        h = float(rng.uniform(0.18, 0.3))
    elif kind == "books":
        n = int(rng.integers(1, 5))
        th = rng.uniform(0.02, 0.05, n)
        w, d, h = 0.26, 0.2, float(th.sum())
    else:
        w, d, h = 0.2, 0.18, 0.08

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        attrs = _clutter(ids)
        if kind == "monitor":
            _add_monitor(mb, pose, attrs, rng, width=w, lift=lift, screen_height=sh)
        elif kind == "laptop":
            mb.add_local_boxes(
                pose,
                [[0.0, 0.0, 0.01], [0.0, -d / 2 + 0.01, 0.02 + 0.105]],
                [[w, d, 0.02], [w, 0.012, 0.21]],
                colour=col * 0.5,
                material=ap.METAL,
                **attrs,
            )
        elif kind in ("mug", "bottle"):
            mb.add_prisms(pose.world([[0.0, 0.0, 0.0]]), w / 2, h, sides=10, colour=col, **attrs)
        elif kind == "books":
            _add_books(mb, pose, attrs, rng, thickness=th, width=w, depth=d)
        else:
            mb.add_local_boxes(pose, [[0.0, 0.0, h / 2]], [w, d, h], colour=col, **attrs)

    return Item(kind, w, d, h, build)


def _add_monitor(
    mb: MeshBuilder,
    pose: Pose,
    attrs: dict[str, int],
    rng: np.random.Generator,
    *,
    width: float,
    lift: float,
    screen_height: float,
) -> None:
    """A monitor's foot, neck and housing, and its screen a little in front of the housing."""
    sh = screen_height
    dark = ap.sample_colour(rng, "screen")
    c = [[0.0, 0.02, 0.008], [0.0, -0.03, lift / 2 + 0.01], [0.0, -0.05, lift + sh / 2]]
    s = [[0.22, 0.18, 0.016], [0.05, 0.03, lift], [width, 0.035, sh]]
    mb.add_local_boxes(pose, c, s, colour=dark * 1.4, material=ap.PLAIN, **attrs)
    mb.add_local_boxes(
        pose,
        [[0.0, -0.03, lift + sh / 2]],
        [width - 0.03, 0.006, sh - 0.03],
        colour=dark,
        material=ap.SCREEN,
        **attrs,
    )


def _add_books(
    mb: MeshBuilder,
    pose: Pose,
    attrs: dict[str, int],
    rng: np.random.Generator,
    *,
    thickness: np.ndarray,
    width: float,
    depth: float,
) -> None:
    """A pile of books of the given thicknesses, each a little askew and of its own colour."""
    th = thickness
    z = np.concatenate([[0.0], np.cumsum(th)[:-1]]) + th / 2
    jitter = rng.uniform(-0.02, 0.02, (th.size, 2))
    centres = np.column_stack([jitter, z])
    cols = ap.sample_colour(rng, "book", th.size)
    sizes = np.stack([np.full(th.size, width - 0.05), np.full(th.size, depth - 0.05), th], 1)
    mb.add_local_boxes(pose, centres, sizes, colour=cols, **attrs)


def make_wall_item(rng: np.random.Generator, height: float) -> tuple[Item, float]:
    """A picture, poster, TV, clock, electric box or AC unit and its mounting height (z of base).

    The item's local +y points away from the wall; its back is at local y = -d/2.
    """
    kind = str(
        rng.choice(
            ["picture", "poster", "tv", "clock", "box", "ac"], p=[0.35, 0.25, 0.1, 0.1, 0.1, 0.1]
        )
    )
    if kind == "picture":
        w, d, h = float(rng.uniform(0.3, 1.2)), float(rng.uniform(0.035, 0.05)), 0.0
        h = float(rng.uniform(0.3, 0.9))
        z = float(rng.uniform(1.2, 1.7))
    elif kind == "poster":
        w, h, d = float(rng.uniform(0.4, 0.9)), float(rng.uniform(0.6, 1.1)), 0.035
        z = float(rng.uniform(1.0, 1.4))
    elif kind == "tv":
        w, h, d = float(rng.uniform(0.9, 1.4)), 0.0, float(rng.uniform(0.05, 0.09))
        h = w * 0.58
        z = float(rng.uniform(1.1, 1.5))
    elif kind == "clock":
        w = h = float(rng.uniform(0.25, 0.4))
        d, z = 0.04, float(min(height - 0.5, rng.uniform(2.0, 2.4)))
    elif kind == "box":
        w, h, d = float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.4, 0.8)), 0.15
        z = float(rng.uniform(0.8, 1.3))
    else:
        w, h, d = float(rng.uniform(0.7, 1.0)), 0.3, float(rng.uniform(0.2, 0.25))
        z = float(height - 0.3 - rng.uniform(0.1, 0.35))
    z = min(z, height - h - 0.05)
    col = ap.sample_colour(rng, "screen" if kind == "tv" else "any")
    if kind in ("box", "ac"):
        col = ap.sample_colour(rng, "cabinet")
    inner = ap.sample_colour(rng, "any")

    def build(mb: MeshBuilder, pose: Pose, ids: Ids) -> None:
        attrs = {"label": CLUTTER, "instance": ids()}
        mb.add_local_boxes(
            pose,
            [[0.0, 0.0, h / 2]],
            [w, d, h],
            colour=col,
            material=ap.SCREEN if kind == "tv" else ap.PLAIN,
            **attrs,
        )
        if kind == "picture" and w > 0.12 and h > 0.12:
            mb.add_local_boxes(
                pose,
                [[0.0, d / 2 + 0.002, h / 2]],
                [w - 0.08, 0.004, h - 0.08],
                colour=inner,
                **attrs,
            )

    return Item(kind, w, d, h, build), z
