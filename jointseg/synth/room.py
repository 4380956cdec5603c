"""``make_room``: one furnished, scanned room with S3DIS ground truth."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Literal

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan
from jointseg.synth.furnish import draw_flags, furnish
from jointseg.synth.layout import Occupancy, Plan
from jointseg.synth.meshes import MeshBuilder, SceneMesh
from jointseg.synth.params import check_count, check_points, check_seed, check_yaw
from jointseg.synth.plans import room_plan
from jointseg.synth.render import STAGE, render, split_quota
from jointseg.synth.scanner import scanner_positions
from jointseg.synth.structure import Ids, build_openings, build_shell, space_look

log = logging.getLogger(__name__)

MAX_SCANNERS = 10


def _check_args(
    seed: int, points: int, shape: str, yaw: float | None, scanners: int | None
) -> tuple[int, int, float | None, int | None]:
    """Validate ``make_room``'s arguments before any random draw, so errors cost nothing."""
    seed = check_seed(seed)
    points = check_points(points)
    if shape not in ("box", "L"):
        raise ConfigError(f"shape must be 'box' or 'L', got {shape!r}")
    yaw = check_yaw(yaw)
    scanners = None if scanners is None else check_count("scanners", scanners, 1, MAX_SCANNERS)
    return seed, points, yaw, scanners


def _draw_room(rng: np.random.Generator, shape: str) -> tuple[float, int, bool, Plan]:
    """The first draws of a room: its yaw, its scanner count, whether it has windows, its plan."""
    drawn_yaw = float(rng.uniform(0.0, 360.0))
    # An L-shaped room needs a scanner in each arm to be seen whole.
    drawn_scanners = int(rng.integers(1, 4) if shape == "box" else rng.integers(2, 4))
    windows = bool(rng.random() < 0.85)
    return drawn_yaw, drawn_scanners, windows, room_plan(rng, shape, windows)


@dataclass(frozen=True)
class RoomScene:
    """A room as built before it is scanned: what :func:`make_room` and
    :func:`jointseg.synth.export.room_mesh` share.

    Attributes
    ----------
    plan : Plan
    mesh : SceneMesh
        Every triangle, in plan coordinates (axis aligned, floor at z 0).
    occupancy : Occupancy
        Where the furniture stands (the scanners keep clear of it).
    drawn_yaw : float
        The yaw the seed draws (degrees), used unless the caller gives one.
    drawn_scanners : int
        The scanner count the seed draws.
    """

    plan: Plan
    mesh: SceneMesh
    occupancy: Occupancy
    drawn_yaw: float
    drawn_scanners: int


def build_room(seed: int, shape: str, progress: ProgressFn | None = None) -> RoomScene:
    """Build the room ``seed`` and ``shape`` draw: plan, shell, openings and furniture, meshed
    (arguments already checked)."""
    rng = np.random.default_rng(seed)
    drawn_yaw, drawn_scanners, windows, plan = _draw_room(rng, shape)
    space = plan.spaces[0]
    flags = draw_flags(rng, space.kind, at_least=4 - int(windows))
    report(progress, STAGE, 0.02)
    mb, ids = MeshBuilder(), Ids()
    looks = [space_look(rng)]
    build_shell(plan, mb, ids, looks, rng)
    build_openings(plan, mb, ids, rng)
    occupancy = furnish(space, plan, mb, ids, rng, looks[0], flags)
    return RoomScene(plan, mb.build(), occupancy, drawn_yaw, drawn_scanners)


def room_layout(seed: int, *, shape: Literal["box", "L"] = "box") -> Plan:
    """The plan :func:`make_room` builds for ``seed`` and ``shape``: the true rooms, wall
    height and thickness, doors and windows (plan coordinates: before the yaw, floor at z 0)."""
    return _draw_room(np.random.default_rng(seed), shape)[3]


def make_room(
    seed: int,
    *,
    points: int = 200_000,
    shape: Literal["box", "L"] = "box",
    yaw: float | None = None,
    scanners: int | None = None,
    progress: ProgressFn | None = None,
) -> Scan:
    """Generate a scanned room so every stage has realistic, labelled test and training data.

    Parameters
    ----------
    seed : int
        Everything random derives from ``np.random.default_rng(seed)``; the same arguments
        give identical arrays. ``yaw`` and ``scanners`` do not change the room itself.
    points : int
        Exact number of points returned (1 000 to 50 000 000).
    shape : {"box", "L"}
        A rectangular room, or an L-shaped one (a box with one corner rectangle removed).
    yaw : float, optional
        Rotation of the whole room about the vertical axis through its centre, in degrees;
        None draws one from the seed, 0 keeps the walls axis aligned.
    scanners : int, optional
        Number of scanner positions (1 to 10); None draws 1-3 from the seed.
    progress : callable, optional
        ``progress("synth", fraction)``.

    Returns
    -------
    Scan
        xyz (m), rgb, labels (S3DIS classes 0-12) and fields ``instance`` (object id, int32),
        ``scanner`` (index of the scanner that saw the point) and ``range`` (m, float32).

    Raises
    ------
    ConfigError
        On a bad ``seed``, ``points``, ``shape``, ``yaw`` or ``scanners``.
    """
    seed, points, yaw, scanners = _check_args(seed, points, shape, yaw, scanners)
    t0 = time.perf_counter()
    room = build_room(seed, shape, progress)
    plan, mesh, space = room.plan, room.mesh, room.plan.spaces[0]
    report(progress, STAGE, 0.1)
    n_scan = scanners if scanners is not None else room.drawn_scanners
    origins = scanner_positions(space, room.occupancy, n_scan, np.random.default_rng([seed, 1]))
    quotas = split_quota(points, np.ones(n_scan))
    scan = render(
        plan,
        mesh,
        origins,
        quotas,
        room.drawn_yaw if yaw is None else yaw,
        np.random.default_rng([seed, 2, n_scan]),
        progress,
    )
    log.info(
        "room seed=%d shape=%s kind=%s: %d triangles, %d points in %.2f s",
        seed,
        shape,
        space.kind,
        mesh.n_triangles,
        points,
        time.perf_counter() - t0,
    )
    return scan
