"""DGCNN's whole-scan inference with the blocks built, gathered and summed on the network's
device, so that a GPU does not wait for the CPU between forward passes.

It follows :meth:`~jointseg.network.dgcnn.predict.DGCNNPredictor.predict` step for step, with the
torch twins of :mod:`.device_blocks` and :mod:`.device_frame`: the same seed gives the same samples,
and the outputs equal the CPU path's up to float rounding (on a GPU the softmax sums are added in
a different order). The scan goes to the device once, the probabilities come back once; the
rare points left in no column (their nearest covered point's output) stay on the CPU.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import torch

from jointseg.network.base import synchronize
from jointseg.network.dgcnn.blocks import fill_unseen
from jointseg.network.dgcnn.device_blocks import (
    block_features_torch,
    column_blocks_torch,
    sample_columns_torch,
)
from jointseg.network.dgcnn.device_frame import frame_torch
from jointseg.network.dgcnn.model import DGCNN
from jointseg.network.dgcnn.params import DGCNNParams
from jointseg.network.dgcnn.room_frame import RoomFrame
from jointseg.network.results import NetworkResult
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

log = logging.getLogger(__name__)
STAGE = "network"


def device_sample_features(
    xyz: torch.Tensor, rgb: torch.Tensor, frame: RoomFrame, params: DGCNNParams
) -> torch.Tensor:
    """:meth:`DGCNNPredictor.sample_features` on the device: (B, M, 9) float32 from the
    samples' float64 ``xyz`` (minus ``frame.origin``) and ``rgb`` in 0-1."""
    p = params
    if p.frame == "room" and p.room_size is not None:
        extent = torch.tensor(
            [*p.room_size, float(frame.extent[2])], dtype=torch.float64, device=xyz.device
        )
        centre = xyz[..., :2].amin(dim=1, keepdim=True) + p.block_size / 2
        shift = torch.cat([centre - extent[:2] / 2, torch.zeros_like(centre[..., :1])], -1)
        return block_features_torch(xyz, rgb, extent, size=p.block_size, shift=shift)
    extent = torch.from_numpy(np.asarray(frame.extent, np.float64)).to(xyz.device)
    return block_features_torch(xyz, rgb, extent, size=p.block_size)


def _to_device(
    scan: Scan, params: DGCNNParams, device: torch.device
) -> tuple[RoomFrame, torch.Tensor, torch.Tensor]:
    """The room frame, and the scan's coordinates (float64, minus the frame origin) and colour
    (0-1) on ``device``."""
    raw = torch.from_numpy(scan.xyz).to(device)
    frame = frame_torch(raw, params)
    xyz = raw - torch.from_numpy(frame.origin).to(device)
    if scan.rgb is None:
        return frame, xyz, torch.zeros((len(scan), 3), dtype=torch.float32, device=device)
    return frame, xyz, torch.from_numpy(scan.rgb).to(device).float() / 255.0


def predict_on_device(
    model: DGCNN,
    params: DGCNNParams,
    scan: Scan,
    *,
    batch_size: int,
    seed: int,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> NetworkResult:
    """Label every point of a non-empty ``scan`` with ``model`` on its own device, as
    :meth:`DGCNNPredictor.predict` does; same timings keys and result."""
    p = params
    device = next(model.parameters()).device
    timings: dict[str, float] = {}
    t = time.perf_counter()
    rng = np.random.default_rng(seed)
    frame, xyz, rgb = _to_device(scan, p, device)
    xy = xyz[:, :2] - xyz[:, :2].amin(dim=0)
    columns = column_blocks_torch(
        xy, size=p.block_size, stride=p.stride, min_points=p.min_block_points
    )
    samples, _ = sample_columns_torch(columns, p.num_points, coverage=p.coverage, rng=rng)
    synchronize(device)
    timings["blocks"] = time.perf_counter() - t
    t = time.perf_counter()
    num_classes = model.num_classes
    prob_sum = torch.zeros((len(scan), num_classes), dtype=torch.float32, device=device)
    seen = torch.zeros(len(scan), dtype=torch.float32, device=device)
    with torch.inference_mode():
        for start in range(0, len(samples), batch_size):
            check_cancel(cancel)
            idx = samples[start : start + batch_size]
            feats = device_sample_features(xyz[idx], rgb[idx], frame, p)
            logits = model(feats, between=lambda: check_cancel(cancel))
            probs = torch.softmax(logits.float(), dim=-1).reshape(-1, num_classes)
            flat = idx.reshape(-1)
            prob_sum.index_add_(0, flat, probs)
            seen.index_add_(0, flat, torch.ones(len(flat), device=device))
            report(progress, STAGE, 0.95 * (start + len(idx)) / len(samples))
        synchronize(device)
    timings["blocks_forward"] = time.perf_counter() - t
    t = time.perf_counter()
    probs_np = (prob_sum / seen.clamp(min=1)[:, None]).cpu().numpy()
    seen_np = seen.cpu().numpy() > 0
    fill_unseen(probs_np, seen_np, scan.xyz)
    labels = probs_np.argmax(axis=1).astype(np.int32)
    timings["project"] = time.perf_counter() - t
    report(progress, STAGE, 1.0)
    log.info(
        "dgcnn (on %s): %d points, %d columns, %d samples, %.1f%% predicted directly",
        device,
        len(scan),
        len(columns),
        len(samples),
        100.0 * seen_np.mean(),
    )
    return NetworkResult(labels, probs_np.astype(np.float32), len(samples), timings)
