"""What the network's head sees: the last decoder layer's per-point features.

Adapting only the head (three point-wise layers, about 5 000 weights) needs the body's output
once per scan; the head then learns in seconds on two cores. The features are averaged over the
crops that saw each grid sub-sampled point, as the pipeline averages the probabilities.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from jointseg.network.anchored import anchored_cloud
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

STAGE = "features"


@dataclass(frozen=True)
class HeadInputs:
    """A scan as the head sees it.

    Attributes
    ----------
    features : (M, C) float32
        The head's input at each grid sub-sampled point, averaged over the crops that saw it.
    probs : (M, K) float32
        The network's own softmax there (the same average), what distillation keeps.
    nearest : (N,) int64
        Each scan point's sub-sampled point (the pipeline's projection).
    """

    features: np.ndarray
    probs: np.ndarray
    nearest: np.ndarray


def head_inputs(
    predictor: Any,
    scan: Scan,
    *,
    seed: int = 0,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> HeadInputs:
    """The head's inputs for every sub-sampled point of ``scan`` (work frame), through torch
    (OpenVINO runs the network whole and shows no intermediate layer)."""
    model = predictor.model
    cloud = anchored_cloud([(scan.xyz, scan.rgb)], predictor.grid_size, scan.xyz.min(axis=0))
    plan = predictor.plan(cloud, seed)
    m = len(cloud.xyz)
    width = model.head[0].in_channels
    feat_sum = torch.zeros((m, width), dtype=torch.float64)
    prob_sum = torch.zeros((m, model.config.num_classes), dtype=torch.float64)
    seen = torch.zeros(m, dtype=torch.float64)
    captured: list[torch.Tensor] = []
    hook = model.head.register_forward_hook(lambda _m, args, _out: captured.append(args[0]))
    was_training = model.training
    model.eval()
    try:
        crops = np.arange(len(plan), dtype=np.int64)
        with torch.inference_mode():
            for batch, done in predictor.batches(cloud, plan, crops, seed):
                check_cancel(cancel)
                batch = batch.to(predictor.device)
                captured.clear()
                logits = model(
                    batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples
                )
                idx = torch.from_numpy(batch.indices.reshape(-1))
                feats = captured[0].reshape(len(idx), width).double().cpu()
                probs = torch.softmax(logits.float(), -1).reshape(len(idx), -1).double().cpu()
                feat_sum.index_add_(0, idx, feats)
                prob_sum.index_add_(0, idx, probs)
                seen.index_add_(0, idx, torch.ones(len(idx), dtype=torch.float64))
                report(progress, STAGE, done / max(len(plan), 1))
    finally:
        hook.remove()
        model.train(was_training)
    keep = seen.clamp(min=1)[:, None]
    return HeadInputs(
        (feat_sum / keep).float().numpy(),
        (prob_sum / keep).float().numpy(),
        np.asarray(cloud.nearest(scan.xyz), dtype=np.int64),
    )
