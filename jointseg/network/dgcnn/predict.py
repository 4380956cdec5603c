"""Whole-scan DGCNN inference with the public S3DIS weights (antao97/dgcnn.pytorch).

The scan is cut into the reference's 1 m columns (overlapping by default), every column into
random 4 096-point samples; each sample gets the reference's 9 features and goes through the
network in batches; every point's softmax outputs are averaged over the samples that contained
it, and a point no sample contained takes those of its nearest predicted neighbour.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from jointseg.exceptions import ConfigError, library_reason
from jointseg.network.backends import Predictor
from jointseg.network.base import NetworkPredictor
from jointseg.network.dgcnn.blocks import (
    block_features,
    column_blocks,
    fill_unseen,
    sample_columns,
)
from jointseg.network.dgcnn.device_predict import predict_on_device
from jointseg.network.dgcnn.model import DGCNN
from jointseg.network.dgcnn.params import DGCNNParams
from jointseg.network.dgcnn.room_frame import RoomFrame, room_frame, scan_frame
from jointseg.network.results import NetworkResult
from jointseg.network.torch_files import read_torch_file, state_mismatch
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

__all__ = [
    "WEIGHTS_SOURCE",
    "DGCNNPredictor",
    "load_dgcnn",
    "load_dgcnn_state",
    "read_dgcnn_card",
]

log = logging.getLogger(__name__)
STAGE = "network"
WEIGHTS_SOURCE = (
    "https://github.com/antao97/dgcnn.pytorch (pretrained/semseg_s3dis/model_1.t7 ... "
    "model_6.t7, MIT; model_i was trained with S3DIS Area i left out)"
)


def load_dgcnn_state(path: str | os.PathLike[str]) -> tuple[DGCNN, dict[str, Any]]:
    """Load a dgcnn.pytorch S3DIS state dict (``model_i.t7``) into :class:`DGCNN`.

    Only tensors are read (``weights_only``); the ``module.`` prefix that ``nn.DataParallel``
    adds is stripped.

    Raises
    ------
    ConfigError
        When the file is missing, unreadable, or not a DGCNN S3DIS state dict.
    """
    path = Path(path)
    state = read_torch_file(path, hint=f"; get DGCNN's weights from {WEIGHTS_SOURCE}")
    if isinstance(state, dict) and isinstance(state.get("state_dict"), dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise ConfigError(f"{path}: not a state dict; expected dgcnn.pytorch's model_i.t7")
    state = {str(k).removeprefix("module."): v for k, v in state.items()}
    model = DGCNN()
    problem = state_mismatch(model, state)
    if problem is not None:
        raise ConfigError(
            f"{path}: not a DGCNN S3DIS state dict (dgcnn.pytorch model_i.t7): {problem}"
        )
    try:
        model.load_state_dict(state)
    except RuntimeError as exc:
        raise ConfigError(
            f"{path}: not a DGCNN S3DIS state dict (dgcnn.pytorch model_i.t7): "
            f"{library_reason(exc, 'it does not load')}"
        ) from exc
    model.eval()
    stem = path.stem
    area = stem.removeprefix("model_") if stem.startswith("model_") else None
    data = f"S3DIS, Area {area} held out" if area and area.isdigit() else "S3DIS (dgcnn.pytorch)"
    card = {"data": data, "source": WEIGHTS_SOURCE, "architecture": "DGCNN semseg, k=20"}
    return model, card


def load_dgcnn(
    path: Path, *, device: str | None, batch_size: int, params: DGCNNParams | None
) -> Predictor:
    """The DGCNN backend's loader (see :mod:`jointseg.network.dgcnn.backend`): a
    :class:`DGCNNPredictor`.

    Raises
    ------
    ConfigError
        When the file is not readable DGCNN weights.
    """
    net, card = load_dgcnn_state(path)
    return DGCNNPredictor(net, card, device=device, batch_size=batch_size, params=params)


def read_dgcnn_card(path: Path) -> tuple[str, str]:
    """What the weights were trained on (from the file name: dgcnn.pytorch ships no card), and
    no further card line."""
    return str(load_dgcnn_state(path)[1]["data"]), ""


class DGCNNPredictor(NetworkPredictor):
    """A loaded DGCNN and the whole-scan block inference around it."""

    name = "dgcnn"
    model: DGCNN

    def __init__(
        self,
        model: DGCNN,
        card: dict[str, Any] | None = None,
        *,
        device: str | None = None,
        batch_size: int = 1,
        params: DGCNNParams | None = None,
        device_path: bool | None = None,
    ) -> None:
        super().__init__(model, card, device=device, batch_size=batch_size, device_path=device_path)
        self.params = params or DGCNNParams()

    def frame(self, scan: Scan) -> RoomFrame:
        """The room frame the normalised coordinates of ``scan`` are computed in."""
        p = self.params
        if p.frame == "scan":
            return scan_frame(scan.xyz)
        return room_frame(scan.xyz, height=p.room_height)

    def predict(
        self,
        scan: Scan,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
        *,
        seed: int = 0,
    ) -> NetworkResult:
        """Label every point of ``scan`` (metres, z up; colour used when present).

        Memory is bounded by the batch: the scan is held once, plus the per-point sums.

        Raises
        ------
        ConfigError
            When the scan is empty.
        Cancelled
            When ``cancel`` is set (checked between batches and inside the forward pass).
        """
        if len(scan) == 0:
            raise ConfigError("cannot run the network on an empty scan")
        if self.on_device:  # blocks built and gathered on the device (device_predict.py)
            return self._predict_on_device(scan, progress, cancel, seed)
        p = self.params
        timings: dict[str, float] = {}
        t = time.perf_counter()
        rng = np.random.default_rng(seed)
        frame = self.frame(scan)
        xyz = scan.xyz - frame.origin
        rgb = (
            np.zeros((len(scan), 3), np.float32)
            if scan.rgb is None
            else scan.rgb.astype(np.float32) / 255.0
        )
        columns = column_blocks(
            xyz[:, :2] - xyz[:, :2].min(axis=0),
            size=p.block_size,
            stride=p.stride,
            min_points=p.min_block_points,
        )
        samples, _ = sample_columns(columns, p.num_points, coverage=p.coverage, rng=rng)
        timings["blocks"] = time.perf_counter() - t
        t = time.perf_counter()
        num_classes = self.model.num_classes
        prob_sum = torch.zeros((len(scan), num_classes), dtype=torch.float32)
        seen = torch.zeros(len(scan), dtype=torch.float32)
        with torch.inference_mode():
            for start in range(0, len(samples), self.batch_size):
                check_cancel(cancel)
                idx = samples[start : start + self.batch_size]
                feats = self.sample_features(xyz[idx], rgb[idx], frame)
                logits = self.model(
                    torch.from_numpy(feats).to(self.device),
                    between=lambda: check_cancel(cancel),
                )
                probs = torch.softmax(logits.float(), dim=-1).cpu().reshape(-1, num_classes)
                flat = torch.from_numpy(idx.reshape(-1))
                prob_sum.index_add_(0, flat, probs)
                seen.index_add_(0, flat, torch.ones(len(flat)))
                report(progress, STAGE, 0.95 * (start + len(idx)) / len(samples))
        timings["blocks_forward"] = time.perf_counter() - t
        t = time.perf_counter()
        probs_np = (prob_sum / seen.clamp(min=1)[:, None]).numpy()
        seen_np = seen.numpy() > 0
        fill_unseen(probs_np, seen_np, scan.xyz)
        labels = probs_np.argmax(axis=1).astype(np.int32)
        timings["project"] = time.perf_counter() - t
        report(progress, STAGE, 1.0)
        log.info(
            "dgcnn: %d points, %d columns, %d samples, %.1f%% predicted directly",
            len(scan),
            len(columns),
            len(samples),
            100.0 * seen_np.mean(),
        )
        return NetworkResult(labels, probs_np.astype(np.float32), len(samples), timings)

    def _predict_on_device(
        self, scan: Scan, progress: ProgressFn | None, cancel: CancelToken | None, seed: int
    ) -> NetworkResult:
        """:meth:`predict` with the blocks built and gathered on the device."""
        return predict_on_device(
            self.model, self.params, scan, batch_size=self.batch_size,
            seed=seed, progress=progress, cancel=cancel,
        )  # fmt: skip

    def sample_features(self, xyz: np.ndarray, rgb: np.ndarray, frame: RoomFrame) -> np.ndarray:
        """The 9 network inputs of a batch of samples, as :func:`block_features` describes.

        Parameters
        ----------
        xyz : ndarray of shape (B, M, 3), metres
            Sampled points minus ``frame.origin``.
        rgb : ndarray of shape (B, M, 3)
            Colour in 0-1.
        frame : RoomFrame

        Returns
        -------
        ndarray of shape (B, M, 9), float32
        """
        p = self.params
        if p.frame == "room" and p.room_size is not None:
            # a scan larger than a room: each block sits in the middle of a room of that size
            extent = np.array([*p.room_size, frame.extent[2]])
            centre = xyz[..., :2].min(axis=1, keepdims=True) + p.block_size / 2
            shift = np.concatenate([centre - extent[:2] / 2, np.zeros_like(centre[..., :1])], -1)
            return block_features(xyz, rgb, extent, size=p.block_size, shift=shift)
        return block_features(xyz, rgb, frame.extent, size=p.block_size)
