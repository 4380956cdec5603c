"""Virtual terrestrial scanner: ray casting from tripod positions into the scene mesh.

Casting rays (uniform on the sphere, minus the blind cone under the tripod) makes occlusion,
shadows behind furniture and the fall of density with range come out as in a real scan. One
Embree scene holds all triangles; rays go in batches, misses (open doors, gaps) are dropped and
more rays are cast until each scanner has delivered its quota of points.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from jointseg.progress import ProgressFn, report
from jointseg.synth.layout import Occupancy, Space
from jointseg.synth.meshes import SceneMesh

log = logging.getLogger(__name__)

MIN_RANGE = 0.3  # m; closer returns are discarded like a real scanner does
MAX_RANGE = 60.0
BLIND_COS = -0.97  # rays steeper downwards than this hit the tripod
BATCH = 1_000_000


@dataclass(frozen=True)
class Hits:
    """Per-point ray-cast results, in scan order (scanner by scanner)."""

    xyz: np.ndarray  # (N, 3) float64, with range noise
    triangle: np.ndarray  # (N,) int64
    normal: np.ndarray  # (N, 3) float32 triangle normals
    direction: np.ndarray  # (N, 3) float32 unit ray directions
    scanner: np.ndarray  # (N,) int32
    range: np.ndarray  # (N,) float32 noisy range


def scanner_positions(
    space: Space, occ: Occupancy, count: int, rng: np.random.Generator
) -> np.ndarray:
    """Tripod positions in free floor space of ``space``, spread apart, at 1.2-1.8 m height."""
    x0, y0, x1, y1 = space.bbox
    cand = np.stack([rng.uniform(x0, x1, 400), rng.uniform(y0, y1, 400)], 1)
    cand = cand[space.contains(cand[:, 0], cand[:, 1], margin=0.7)]
    if cand.shape[0] == 0:
        cx, cy = (
            0.5 * (space.rects[0][0] + space.rects[0][2]),
            0.5 * (space.rects[0][1] + space.rects[0][3]),
        )
        cand = np.array([[cx, cy]])
    boxes = occ.boxes
    boxes = boxes[boxes[:, 2] < 1.9] if boxes.size else boxes
    if boxes.size:
        dx = np.maximum(
            0.0,
            np.maximum(boxes[None, :, 0] - cand[:, None, 0], cand[:, None, 0] - boxes[None, :, 3]),
        )
        dy = np.maximum(
            0.0,
            np.maximum(boxes[None, :, 1] - cand[:, None, 1], cand[:, None, 1] - boxes[None, :, 4]),
        )
        clearance = np.sqrt(dx**2 + dy**2).min(axis=1)
    else:
        clearance = np.full(cand.shape[0], 1.0)
    # Operators put the tripod in the open and spread the positions over the room.
    clear = np.minimum(clearance, 1.0) + rng.uniform(0.0, 0.3, clearance.size)
    clear[clearance < 0.3] -= 10.0
    chosen = [cand[int(np.argmax(clear))]]
    while len(chosen) < count:
        d = np.min(np.linalg.norm(cand[:, None, :] - np.array(chosen)[None], axis=2), axis=1)
        chosen.append(cand[int(np.argmax(clear + np.minimum(d, 5.0)))])
    xy = np.array(chosen[:count])
    z = rng.uniform(1.2, 1.8, (xy.shape[0], 1))
    return np.hstack([xy, z])


def _directions(rng: np.random.Generator, n: int) -> np.ndarray:
    """Unit vectors uniform on the sphere without the blind cone below the scanner."""
    z = rng.uniform(BLIND_COS, 1.0, n)
    phi = rng.uniform(0.0, 2 * np.pi, n)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1).astype(np.float32)


def make_scene(mesh: SceneMesh) -> o3d.t.geometry.RaycastingScene:
    """One Embree scene holding every triangle of ``mesh`` (primitive id = triangle index)."""
    scene = o3d.t.geometry.RaycastingScene(nthreads=0)
    scene.add_triangles(
        o3d.core.Tensor.from_numpy(mesh.vertices), o3d.core.Tensor.from_numpy(mesh.triangles)
    )
    return scene


def occluded(
    scene: o3d.t.geometry.RaycastingScene,
    points: np.ndarray,
    normals: np.ndarray,
    targets: np.ndarray,
) -> np.ndarray:
    """Whether the segment from each point (nudged off its surface) to its target is blocked."""
    out = np.zeros(points.shape[0], dtype=bool)
    ok = np.isfinite(targets).all(axis=1)
    idx = np.flatnonzero(ok)
    for a in range(0, idx.size, BATCH):
        sel = idx[a : a + BATCH]
        start = points[sel] + normals[sel] * 0.004
        d = targets[sel] - start
        dist = np.linalg.norm(d, axis=1)
        rays = np.empty((sel.size, 6), dtype=np.float32)
        rays[:, :3] = start
        rays[:, 3:] = d / np.maximum(dist, 1e-9)[:, None]
        t = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))["t_hit"].numpy()
        out[sel] = t < dist - 0.05
    return out


def cast(
    scene: o3d.t.geometry.RaycastingScene,
    origins: np.ndarray,
    quotas: np.ndarray,
    rng: np.random.Generator,
    progress: ProgressFn | None = None,
    stage: str = "synth",
    span: tuple[float, float] = (0.0, 1.0),
) -> Hits:
    """Cast rays from each origin until it has ``quotas[i]`` hits; add range noise."""
    total = int(quotas.sum())
    parts: list[tuple[np.ndarray, ...]] = []
    done = 0
    for s, (origin, quota) in enumerate(zip(origins, quotas, strict=True)):
        have, rate, batches = 0, 0.97, 0
        while have < quota:
            batches += 1
            if batches > 200:
                raise RuntimeError(f"scanner {s} at {origin.tolist()} sees almost nothing")
            n = min(BATCH, int((quota - have) / max(rate, 0.05) * 1.02) + 256)
            dirs = _directions(rng, n)
            rays = np.empty((n, 6), dtype=np.float32)
            rays[:, :3] = origin
            rays[:, 3:] = dirs
            res = scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
            t = res["t_hit"].numpy()
            ok = np.isfinite(t) & (t > MIN_RANGE) & (t < MAX_RANGE)
            rate = max(0.05, float(ok.mean()))
            idx = np.flatnonzero(ok)[: quota - have]
            tri = res["primitive_ids"].numpy()[idx].astype(np.int64)
            nrm = res["primitive_normals"].numpy()[idx]
            parts.append(
                (dirs[idx], t[idx], tri, nrm, np.full(idx.size, s, dtype=np.int32), origin)
            )
            have += idx.size
            done += idx.size
            report(progress, stage, span[0] + (span[1] - span[0]) * done / max(total, 1))
    dirs = np.concatenate([p[0] for p in parts])
    t = np.concatenate([p[1] for p in parts]).astype(np.float64)
    sigma = 0.0015 + 0.0007 * t
    t_noisy = t + rng.standard_normal(t.size) * sigma
    orig = np.concatenate([np.broadcast_to(p[5], (p[0].shape[0], 3)) for p in parts])
    xyz = orig.astype(np.float64) + dirs.astype(np.float64) * t_noisy[:, None]
    log.debug("cast %d points from %d scanners", xyz.shape[0], len(quotas))
    return Hits(
        xyz=xyz,
        triangle=np.concatenate([p[2] for p in parts]),
        normal=np.concatenate([p[3] for p in parts]),
        direction=dirs,
        scanner=np.concatenate([p[4] for p in parts]),
        range=t_noisy.astype(np.float32),
    )
