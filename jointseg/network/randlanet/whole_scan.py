"""RandLA-Net's whole-scan inference around any forward pass, in numpy: the anchored grid
sub-sample, the crop plan, the crops' summed outputs (the predictor's ``crop_sums``), then every
point's probabilities; or a tile's share of it. Shared by the torch predictor
(:mod:`~jointseg.network.randlanet.predict`) and the torch-free compiled one
(:mod:`~jointseg.network.randlanet.compiled`), so both give the same labels.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np

from jointseg.network.anchored import (
    AnchoredCloud,
    CropPlan,
    anchored_cloud,
    crop_members,
    point_probs,
    tile_sums,
)
from jointseg.network.randlanet.config import RandLANetConfig
from jointseg.network.randlanet.crop_arrays import CropArrays, crop_arrays
from jointseg.network.results import CellSums, NetworkResult
from jointseg.progress import CancelToken, ProgressFn, report
from jointseg.scan import Scan

log = logging.getLogger(__name__)

STAGE = "network"


class CropSummer(Protocol):
    """What the whole-scan inference asks of a predictor."""

    params: Any

    @property
    def grid_size(self) -> float: ...

    def plan(self, cloud: AnchoredCloud, seed: int) -> CropPlan: ...

    def crop_sums(
        self,
        cloud: AnchoredCloud,
        plan: CropPlan,
        crops: np.ndarray,
        *,
        seed: int,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
    ) -> tuple[np.ndarray, np.ndarray]: ...


def crop_batches(
    cloud: AnchoredCloud,
    plan: CropPlan,
    crops: np.ndarray,
    seed: int,
    batch_size: int,
    config: RandLANetConfig,
) -> Iterator[tuple[CropArrays, int]]:
    """The inputs of the crops ``crops`` (indices into ``plan``), ``batch_size`` at a time,
    each with the number of crops done after it. Depends only on the geometry, never on the
    network's outputs, so it runs a batch ahead in a thread (:class:`Prefetcher`)."""
    for first in range(0, len(crops), batch_size):
        chosen = crops[first : first + batch_size]
        members = [crop_members(cloud, plan, int(c), seed) for c in chosen]
        batch = [(cloud.xyz[i], cloud.rgb[i], None, i) for i in members]
        yield crop_arrays(batch, config), first + len(chosen)


def add_crop_outputs(
    prob_sum: np.ndarray, seen: np.ndarray, logits: np.ndarray, indices: np.ndarray
) -> None:
    """Add a batch's softmax outputs (from logits (B, N, C)) to ``prob_sum`` (M, C) float64
    and its counts to ``seen`` (M,) at the crops' points ``indices`` (B, N).

    Why one function, in numpy: the torch and the compiled predictors then give the same
    sums to the last bit from the same logits, so a tile run by either merges alike.
    """
    classes = prob_sum.shape[1]
    z = np.asarray(logits, dtype=np.float32).reshape(-1, classes)
    z = z - z.max(axis=1, keepdims=True)
    probs = np.exp(z)
    probs /= probs.sum(axis=1, keepdims=True)
    flat = np.asarray(indices).reshape(-1)
    np.add.at(prob_sum, flat, probs.astype(np.float64))
    np.add.at(seen, flat, 1.0)  # only the crops' points: a tile's cloud has a million cells


def predict_whole(
    net: CropSummer,
    scan: Scan,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
    seed: int,
) -> NetworkResult:
    """Label every point of a (non-empty) ``scan`` with ``net``'s crops."""
    timings: dict[str, float] = {}
    t = time.perf_counter()
    cloud = anchored_cloud([(scan.xyz, scan.rgb)], net.grid_size, scan.xyz.min(axis=0))
    plan = net.plan(cloud, seed)
    timings["subsample"] = time.perf_counter() - t
    t = time.perf_counter()
    crops = np.arange(len(plan))
    prob_sum, seen = net.crop_sums(cloud, plan, crops, seed=seed, progress=progress, cancel=cancel)
    timings["crops"] = time.perf_counter() - t
    t = time.perf_counter()
    params = net.params
    labels, probs = point_probs(
        cloud,
        prob_sum,
        seen,
        scan.xyz,
        params.absent_share,
        params.absent_max_cells,
        params.projection,
    )
    timings["project"] = time.perf_counter() - t
    report(progress, STAGE, 1.0)
    log.info("network: %d points, %d sub-sampled, %d crops", len(scan), len(cloud.xyz), len(plan))
    return NetworkResult(labels, probs, len(plan), timings)


def predict_tile(
    net: CropSummer,
    scan: Scan,
    plan: CropPlan,
    lower: np.ndarray,
    crops: np.ndarray,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
    seed: int,
) -> CellSums:
    """A tile's share of a whole-scan inference: the crops ``crops`` of the whole scan's
    ``plan``, evaluated on the tile's points."""
    cloud = anchored_cloud([(scan.xyz, scan.rgb)], net.grid_size, lower)
    prob_sum, seen = net.crop_sums(cloud, plan, crops, seed=seed, progress=progress, cancel=cancel)
    report(progress, STAGE, 1.0)
    return tile_sums(cloud, prob_sum, seen, scan.xyz, net.params.projection)
