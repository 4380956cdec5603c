"""Crop plans and crop members computed in torch on a device, agreeing with the CPU's.

Why: on a GPU, the possibility scheme's K-nearest searches (:func:`plan_crops`) and each crop's
members (:func:`crop_members`) are a distance vector and a ``topk`` over the sub-sample: cheap
there, where the KD-tree searches on the CPU kept the device waiting. They use the same random
draws as the CPU versions (numpy generators, cheap), distances in float64 from float32 points
summed in cKDTree's order, and so pick the same centres and the same members, in the same order
(points at exactly equal distance may come in another order).
"""

from __future__ import annotations

import numpy as np
import torch

from jointseg.network.anchored import CropPlan


def squared_distances(points: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
    """(M,) float64 squared distances of float32 ``points`` (M, 3) to ``centre`` (3,), summed
    x, y, z in that order, as cKDTree does."""
    diff = points.to(torch.float64) - centre.to(points.device, torch.float64)
    sq = diff * diff
    return sq[:, 0] + sq[:, 1] + sq[:, 2]


def k_nearest(
    points: torch.Tensor, centre: torch.Tensor, k: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """Distances (float64, as cKDTree returns them) and indices of the ``k`` points nearest
    ``centre``, nearest first."""
    d2, idx = torch.topk(squared_distances(points, centre), k, largest=False, sorted=True)
    return torch.sqrt(d2), idx


def device_plan_crops(
    xyz: torch.Tensor, num_points: int, min_possibility: float, seed: int
) -> CropPlan:
    """:func:`jointseg.network.anchored.plan_crops` over the sub-sampled centroids ``xyz``
    (M, 3) float32 on a device. One synchronisation per crop (is every point covered?)."""
    m = len(xyz)
    crop_size = min(num_points, max(m, 1024))
    rng = np.random.default_rng(seed)
    possibility = torch.as_tensor(rng.random(m) * 1e-3, device=xyz.device)
    k = min(crop_size, m)
    points = xyz.to(torch.float64)  # once, not per crop
    centres: list[torch.Tensor] = []
    radius: list[torch.Tensor] = []
    while True:
        low, at = possibility.min(dim=0)
        if float(low) >= min_possibility:
            break
        centre = xyz[at]
        dist, idx = k_nearest(points, centre, k)
        d2 = dist * dist
        top = d2.max()
        possibility[idx] += 1 - d2 / top.clamp(min=1e-12)
        centres.append(centre)
        radius.append(torch.sqrt(top))
    if not centres:
        return CropPlan(np.zeros((0, 3), np.float32), np.zeros(0, np.float32), crop_size)
    return CropPlan(
        torch.stack(centres).cpu().numpy().astype(np.float32).reshape(-1, 3),
        torch.stack(radius).cpu().numpy().astype(np.float32),
        crop_size,
    )


def member_order(crop_size: int, k: int, seed: int, crop: int) -> np.ndarray:
    """Positions (in nearest-first order) of crop ``crop``'s points in its own random order:
    the draws :func:`crop_members` makes, on positions instead of point indices."""
    rng = np.random.default_rng([seed, crop])
    positions = np.arange(k)
    if k < crop_size:
        extra = rng.choice(positions, size=crop_size - k, replace=True)
        positions = np.concatenate([positions, extra])
    return rng.permutation(positions)


def device_crop_members(xyz: torch.Tensor, plan: CropPlan, crop: int, seed: int) -> torch.Tensor:
    """Indices into ``xyz`` (float32, or the same values in float64 to save a conversion per
    crop) of crop ``crop``'s points, on ``xyz``'s device: the same as
    :func:`jointseg.network.anchored.crop_members`."""
    k = min(plan.crop_size, len(xyz))
    centre = torch.as_tensor(plan.centres[crop], device=xyz.device)
    _, idx = k_nearest(xyz, centre, k)
    order = torch.as_tensor(member_order(plan.crop_size, k, seed, crop), device=xyz.device)
    return idx[order]
