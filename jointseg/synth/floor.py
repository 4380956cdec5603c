"""``make_floor``: several rooms joined by doors onto a corridor, scanned from each space."""

from __future__ import annotations

import logging
import time

import numpy as np

from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan
from jointseg.synth.furnish import draw_flags, furnish
from jointseg.synth.layout import Plan
from jointseg.synth.meshes import MeshBuilder
from jointseg.synth.params import check_count, check_points, check_seed, check_yaw
from jointseg.synth.plans import floor_plan
from jointseg.synth.render import STAGE, render, split_quota
from jointseg.synth.scanner import scanner_positions
from jointseg.synth.structure import Ids, build_openings, build_shell, space_look

log = logging.getLogger(__name__)

MAX_ROOMS = 32


def floor_layout(seed: int, *, rooms: int = 4) -> Plan:
    """The plan :func:`make_floor` builds for ``seed`` and ``rooms``: the true spaces (rooms and
    the corridor), wall height and thickness, doors and windows (plan coordinates)."""
    rng = np.random.default_rng(check_seed(seed))
    rng.uniform(0.0, 360.0)  # the yaw, drawn first
    return floor_plan(rng, check_count("rooms", rooms, 1, MAX_ROOMS))


def make_floor(
    seed: int,
    *,
    rooms: int = 4,
    points: int = 1_000_000,
    yaw: float | None = None,
    progress: ProgressFn | None = None,
) -> Scan:
    """Generate a scanned building level, for tests and training beyond single rooms.

    ``rooms`` rooms (1 to 32) line both sides of a corridor; every room has a door onto the
    corridor (some open, some closed), some neighbours share a door, exterior walls have
    windows. Scanners stand in every room and along the corridor; ``points`` (exact) are split
    across spaces by floor area. Other arguments and the returned fields are as in
    :func:`jointseg.synth.make_room`.

    Raises
    ------
    ConfigError
        On a bad ``seed``, ``rooms``, ``points`` or ``yaw``.
    """
    seed = check_seed(seed)
    rooms = check_count("rooms", rooms, 1, MAX_ROOMS)
    points = check_points(points)
    yaw = check_yaw(yaw)
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    drawn_yaw = float(rng.uniform(0.0, 360.0))
    plan = floor_plan(rng, rooms)  # floor_layout draws the same
    mb, ids = MeshBuilder(), Ids()
    looks = [space_look(rng, corridor=sp.kind == "corridor") for sp in plan.spaces]
    build_shell(plan, mb, ids, looks, rng)
    build_openings(plan, mb, ids, rng)
    srng = np.random.default_rng([seed, 1])
    origins, weights = [], []
    for i, sp in enumerate(plan.spaces):
        flags = draw_flags(rng, sp.kind)
        occ = furnish(sp, plan, mb, ids, rng, looks[sp.index], flags)
        if sp.kind == "corridor":
            x0, _, x1, _ = sp.bbox
            n = max(1, round((x1 - x0) / 7.0))
        else:
            n = 1 + int(sp.area > 30.0)
        pos = scanner_positions(sp, occ, n, srng)
        origins.append(pos)
        weights += [sp.area / n] * n
        report(progress, STAGE, 0.1 * (i + 1) / len(plan.spaces))
    mesh = mb.build()
    quotas = split_quota(points, np.array(weights))
    scan = render(
        plan,
        mesh,
        np.concatenate(origins),
        quotas,
        drawn_yaw if yaw is None else yaw,
        np.random.default_rng([seed, 2]),
        progress,
    )
    log.info(
        "floor seed=%d rooms=%d: %d triangles, %d points in %.2f s",
        seed,
        rooms,
        mesh.n_triangles,
        points,
        time.perf_counter() - t0,
    )
    return scan
