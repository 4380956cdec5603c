"""RandLA-Net's batches of crops built on the network's device, for whole-scan inference.

Why: on a GPU, building a batch on the CPU (KD-tree searches per crop and layer, then copies)
took most of an inference while the device waited. Here a batch is gathered from the
sub-sample already on the device (:class:`jointseg.network.device_grid.DeviceCloud`), with the
same crops as the CPU path (:func:`device_crop_members`) and the exact blocked neighbour search
of :mod:`jointseg.network.randlanet.knn`; the features are those of
:func:`jointseg.network.randlanet.crops.build_batch`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import torch

from jointseg.network.anchored import CropPlan
from jointseg.network.device_crops import device_crop_members
from jointseg.network.device_grid import DeviceCloud
from jointseg.network.randlanet.knn import layer_indices
from jointseg.network.randlanet.model import RandLANetConfig


@dataclass(frozen=True)
class DeviceBatch:
    """Network inputs for B crops, on the device, and the crops' indices into the cloud."""

    features: torch.Tensor  # (B, N, 6)
    coords: list[torch.Tensor]
    neighbours: list[torch.Tensor]
    pools: list[torch.Tensor]
    upsamples: list[torch.Tensor]
    indices: torch.Tensor  # (B, N) int64


def device_batch(cloud: DeviceCloud, members: torch.Tensor, config: RandLANetConfig) -> DeviceBatch:
    """The batch of crops whose points are ``members`` (B, N) (each already in its random
    order): xyz centred in x and y per crop, plus rgb, and the per-layer indices."""
    pts = cloud.xyz[members]
    pts[..., :2] -= pts[..., :2].mean(dim=1, keepdim=True)
    features = torch.cat([pts, cloud.rgb[members]], dim=2)
    coords, neighbours, pools, ups = layer_indices(pts, config)
    return DeviceBatch(features, coords, neighbours, pools, ups, members)


def device_batches(
    cloud: DeviceCloud,
    plan: CropPlan,
    crops: np.ndarray,
    *,
    seed: int,
    config: RandLANetConfig,
    batch_size: int,
) -> Iterator[tuple[DeviceBatch, int]]:
    """Batches of the crops ``crops`` (indices into ``plan``), each with the number of crops
    done after it; only geometry, so a :class:`Prefetcher` may run it ahead."""
    points = cloud.xyz.to(torch.float64)  # once, not per crop
    for first in range(0, len(crops), batch_size):
        chosen = crops[first : first + batch_size]
        members = torch.stack(
            [device_crop_members(points, plan, int(crop), seed) for crop in chosen]
        )
        yield device_batch(cloud, members, config), first + len(chosen)


def add_outputs(
    prob_sum: torch.Tensor, seen: torch.Tensor, batch: DeviceBatch, logits: torch.Tensor
) -> None:
    """Add a batch's softmax outputs (float64) to the per-point sums and crop counts."""
    probs = torch.softmax(logits.float(), dim=-1).double()
    flat = batch.indices.reshape(-1)
    prob_sum.index_add_(0, flat, probs.reshape(len(flat), -1))
    seen.index_add_(0, flat, torch.ones(len(flat), dtype=torch.float64, device=seen.device))
