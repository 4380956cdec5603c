"""From a built scene to a :class:`~jointseg.scan.Scan`: scan, look up, shade, rotate."""

from __future__ import annotations

import logging
import math

import numpy as np

from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan
from jointseg.synth.appearance import facing_normals, light_owner, nearest_light, shade
from jointseg.synth.layout import Plan
from jointseg.synth.meshes import SceneMesh
from jointseg.synth.scanner import cast, make_scene, occluded

log = logging.getLogger(__name__)

STAGE = "synth"


def split_quota(total: int, weights: np.ndarray) -> np.ndarray:
    """Integers proportional to ``weights`` that sum exactly to ``total``."""
    w = np.asarray(weights, dtype=np.float64)
    raw = total * w / w.sum()
    out = np.floor(raw).astype(np.int64)
    rest = total - int(out.sum())
    order = np.argsort(-(raw - out), kind="stable")
    out[order[:rest]] += 1
    return out


def turn_about_centre(xyz: np.ndarray, plan: Plan, yaw_deg: float) -> np.ndarray:
    """``xyz`` turned by ``yaw_deg`` about the vertical axis through the centre of the plan's
    outline: how a scene built axis aligned is placed (its points, or its mesh's vertices)."""
    if yaw_deg % 360.0 == 0.0:
        return xyz
    x0, y0, x1, y1 = plan.outline
    cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    a = math.radians(yaw_deg)
    c, s = math.cos(a), math.sin(a)
    dx, dy = xyz[:, 0] - cx, xyz[:, 1] - cy
    return np.stack([cx + c * dx - s * dy, cy + s * dx + c * dy, xyz[:, 2]], 1)


def render(
    plan: Plan,
    mesh: SceneMesh,
    origins: np.ndarray,
    quotas: np.ndarray,
    yaw_deg: float,
    rng: np.random.Generator,
    progress: ProgressFn | None = None,
) -> Scan:
    """Scan ``mesh`` from ``origins`` and turn the hits into a labelled, coloured scan.

    The scene is built axis aligned; the finished points are rotated by ``yaw_deg`` about the
    vertical axis through the centre of the plan's outline.
    """
    scene = make_scene(mesh)
    hits = cast(scene, origins, quotas, rng, progress, STAGE, (0.1, 0.8))
    tri = hits.triangle
    light_sets = [
        (r, np.asarray(sp.lights, dtype=np.float64).reshape(-1, 3))
        for sp in plan.spaces
        for r in sp.rects
    ]
    normals = facing_normals(hits.normal, hits.direction)
    owner = light_owner(hits.xyz, light_sets)
    shadowed = occluded(scene, hits.xyz, normals, nearest_light(hits.xyz, light_sets, owner))
    report(progress, STAGE, 0.88)
    n_scan = len(origins)
    gains = rng.uniform(0.92, 1.08, (n_scan, 1)) * (1 + rng.normal(0, 0.015, (n_scan, 3)))
    rgb = shade(
        hits.xyz,
        normals,
        mesh.colour[tri],
        mesh.material[tri],
        light_sets,
        owner,
        shadowed,
        gains[hits.scanner],
        rng,
    )
    report(progress, STAGE, 0.95)
    scan = Scan(
        xyz=turn_about_centre(hits.xyz, plan, yaw_deg),
        rgb=rgb,
        labels=mesh.label[tri],
        fields={
            "instance": mesh.instance[tri].astype(np.int32),
            "scanner": hits.scanner.astype(np.int32),
            "range": hits.range,
        },
        source_format="synthetic",
    )
    report(progress, STAGE, 1.0)
    return scan
