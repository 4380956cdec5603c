"""Random floor plans: a box or L-shaped room, or rooms on both sides of a corridor.

Dimensions follow office buildings like the S3DIS areas: rooms 3-12 m a side, ceilings
2.5-4 m, doors 0.85-1.8 m wide, windows only in exterior walls.
"""

from __future__ import annotations

import math

import numpy as np

from jointseg.synth.layout import (
    Opening,
    Plan,
    Space,
    WallFace,
    compute_faces,
    door_opening,
    window_opening,
)

ROOM_KINDS = ("office", "conference", "classroom", "lounge", "storage")


def room_kind(rng: np.random.Generator, area: float) -> str:
    """Room type, with small rooms biased to offices and storage."""
    if area < 14:
        p = [0.6, 0.1, 0.0, 0.1, 0.2]
    else:
        p = [0.42, 0.22, 0.15, 0.08, 0.13]
    return str(rng.choice(ROOM_KINDS, p=p))


def _side(rng: np.random.Generator, lo: float = 3.0, hi: float = 12.0) -> float:
    """A room side length in [lo, hi], most often 4-8 m."""
    return float(lo + (hi - lo) * rng.beta(1.6, 2.6))


def _add_windows(
    rng: np.random.Generator,
    plan: Plan,
    faces: list[WallFace],
    used: dict[int, list[tuple[float, float]]],
    per_face: float,
) -> None:
    for f in faces:
        n = max(1, int(rng.poisson(per_face * f.length / 4.0)))
        for _ in range(n):
            o = window_opening(rng, f, used, id(f), plan.height, plan.thickness)
            if o is not None:
                plan.openings.append(o)


def room_plan(rng: np.random.Generator, shape: str, windows: bool) -> Plan:
    """One room, box or L-shaped, with 1-3 doors and (if ``windows``) windows on 1-2 walls."""
    height = float(rng.uniform(2.5, 4.0))
    thickness = float(rng.uniform(0.15, 0.3))
    if shape == "box":
        w, d = _side(rng), _side(rng)
        rects = [(0.0, 0.0, w, d)]
    else:
        w, d = _side(rng, 5.0, 12.0), _side(rng, 5.0, 12.0)
        a, b = w * rng.uniform(0.3, 0.6), d * rng.uniform(0.3, 0.6)
        rects = [(0.0, 0.0, w, d - b), (0.0, d - b, w - a, d)]
        corner = int(rng.integers(0, 4))
        if corner & 1:
            rects = [(w - r[2], r[1], w - r[0], r[3]) for r in rects]
        if corner & 2:
            rects = [(r[0], d - r[3], r[2], d - r[1]) for r in rects]
    space = Space(0, "", [(float(a), float(b), float(c), float(d)) for a, b, c, d in rects])
    space.kind = room_kind(rng, space.area)
    plan = Plan([space], [], height, thickness)
    compute_faces(plan.spaces, thickness)
    used: dict[int, list[tuple[float, float]]] = {}
    faces = sorted(space.faces, key=lambda f: -f.length)
    n_doors = int(rng.choice([1, 2, 3], p=[0.3, 0.45, 0.25]))
    for _ in range(n_doors * 3):
        if sum(o.kind == "door" for o in plan.openings) >= n_doors:
            break
        f = faces[int(rng.integers(0, len(faces)))]
        o = door_opening(rng, f, used, id(f), height, thickness, open_prob=0.3)
        if o is not None:
            plan.openings.append(o)
    if windows:
        k = 1 if rng.random() < 0.6 else 2
        pick = rng.permutation(min(3, len(faces)))[:k]
        _add_windows(rng, plan, [faces[i] for i in sorted(pick)], used, per_face=1.0)
    return plan


def floor_plan(rng: np.random.Generator, rooms: int) -> Plan:
    """``rooms`` rooms on both sides of a corridor, each with a door onto it."""
    height = float(rng.uniform(2.6, 3.6))
    t = float(rng.uniform(0.12, 0.22))
    cw = float(rng.uniform(1.8, 3.0))
    n_north = math.ceil(rooms / 2)
    counts = [n_north, rooms - n_north]
    widths = [rng.uniform(3.0, 7.0, n) for n in counts]
    lengths = [w.sum() + (len(w) - 1) * t if len(w) else 0.0 for w in widths]
    length = float(max(lengths))
    for k in range(2):
        if len(widths[k]):
            widths[k] = widths[k] * (length - (len(widths[k]) - 1) * t) / widths[k].sum()
    depths = rng.uniform(4.0, 8.0, 2)
    spaces = [Space(0, "corridor", [(0.0, 0.0, length, cw)])]
    for k, sign in ((0, 1), (1, -1)):
        x = 0.0
        for w in widths[k]:
            if sign > 0:
                r = (x, cw + t, x + float(w), cw + t + float(depths[0]))
            else:
                r = (x, -t - float(depths[1]), x + float(w), -t)
            sp = Space(len(spaces), "", [r])
            sp.kind = room_kind(rng, sp.area)
            spaces.append(sp)
            x += float(w) + t
    plan = Plan(spaces, [], height, t)
    compute_faces(spaces, t)
    used: dict[int, list[tuple[float, float]]] = {}
    for sp in spaces[1:]:
        for f in sp.faces:
            if f.other == 0:
                n = 1 + int(f.length > 6.0 and rng.random() < 0.5)
                for _ in range(n):
                    o = door_opening(rng, f, used, id(f), height, t, open_prob=0.5)
                    if o is not None:
                        plan.openings.append(o)
            elif f.other is not None and f.other > sp.index and rng.random() < 0.25:
                o = door_opening(rng, f, used, id(f), height, t, open_prob=0.4)
                if o is not None:
                    plan.openings.append(o)
        if not any(o.face.space == sp.index and o.kind == "door" for o in plan.openings):
            f = next(f for f in sp.faces if f.other == 0)
            o = door_opening(rng, f, used, id(f), height, t, open_prob=0.5)
            if o is None:  # a narrow room: squeeze a narrow door in
                mid = 0.5 * (f.u0 + f.u1)
                o = Opening("door", f, mid - 0.42, mid + 0.42, 0.0, 2.05, t, 0.0)
            plan.openings.append(o)
        exterior = [f for f in sp.faces if f.other is None and f.length > 2.0]
        if exterior and rng.random() < 0.85:
            far = max(exterior, key=lambda f: f.length)
            _add_windows(rng, plan, [far], used, per_face=1.2)
    for f in spaces[0].faces:
        if f.other is None and f.length < cw + 0.5 and rng.random() < 0.5:
            o = window_opening(rng, f, used, id(f), height, t)
            if o is not None:
                plan.openings.append(o)
    return plan
