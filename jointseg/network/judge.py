"""A loaded network as the frame stage's judge (:mod:`jointseg.frame.judge`): a few crops of a
scan's subsample labelled in one batch, cheap enough to run once per candidate frame."""

from __future__ import annotations

from typing import Any

import numpy as np

from jointseg.labeller import LabelFn
from jointseg.network.anchored import CropPlan, anchored_cloud
from jointseg.network.pending import PendingPredictor
from jointseg.scan import Scan

#: Crops per candidate frame, spread along the scan's longest horizontal direction.
CROPS = 1
#: Points labelled by a network without crops (DGCNN and others), per candidate.
GENERIC_POINTS = 16_384


def _cropping(predictor: Any) -> Any:
    """The predictor, or the first member of an ensemble, that labels crops of a grid
    sub-sample (RandLA-Net); None when there is none."""
    for candidate in [predictor, *getattr(predictor, "members", [])]:
        if all(hasattr(candidate, a) for a in ("crop_sums", "grid_size", "num_points")):
            if not getattr(candidate, "on_device", False):
                return candidate
    return None


def crop_labeller(predictor: Any, *, crops: int = CROPS, seed: int = 0) -> LabelFn | None:
    """A :data:`~jointseg.labeller.LabelFn` from a loaded predictor; None for one that is
    no loaded network (no ``model``: a remote or stand-in predictor), which the frame stage
    cannot ask cheaply and without a way to cancel it. A network still loading
    (:class:`~jointseg.network.pending.PendingPredictor`, always a loaded network's stand-in)
    is waited for only when the frame stage asks it."""
    if isinstance(predictor, PendingPredictor):
        pending = predictor

        def when_loaded(xyz: np.ndarray, rgb: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
            label = crop_labeller(pending.get(), crops=crops, seed=seed)
            if label is None:
                raise TypeError(f"{type(pending.get()).__name__} cannot judge a frame")
            return label(xyz, rgb)

        return when_loaded
    net = _cropping(predictor)
    if net is None:
        if getattr(predictor, "model", None) is None:
            return None
        return _generic(predictor, seed)

    def label(xyz: np.ndarray, rgb: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        lower = xyz.min(axis=0)
        cloud = anchored_cloud([(xyz, rgb)], net.grid_size, lower)
        m = len(cloud.xyz)
        size = min(int(net.num_points), max(m, 1024))
        centres = cloud.xyz[np.unique(cloud.tree.query(_targets(cloud.xyz, crops))[1])]
        dist, _ = cloud.tree.query(centres, k=[min(size, m)], workers=-1)
        plan = CropPlan(centres.astype(np.float32), np.asarray(dist, np.float32).reshape(-1), size)
        prob_sum, seen = net.crop_sums(cloud, plan, np.arange(len(plan)), seed=seed)
        hit = seen > 0
        return cloud.xyz[hit] + lower, prob_sum[hit] / seen[hit, None]

    return label


def _targets(xyz: np.ndarray, crops: int) -> np.ndarray:
    """(crops, 3) crop centres at mid-height, spread along the longest horizontal direction:
    a crop around a floor point would see no ceiling, and one around a point nearest to the
    same middle holds nearly the same points in every candidate frame, so the frames differ mostly
    in how they are turned."""
    lo, hi = np.quantile(xyz[:, 2], [0.01, 0.99])
    mid = np.median(xyz[:, :2], axis=0)
    flat = xyz[:, :2] - mid
    _, vecs = np.linalg.eigh(flat.T @ flat)
    along = flat @ vecs[:, -1]
    offsets = np.quantile(along, (np.arange(crops) + 0.5) / crops) if crops > 1 else np.zeros(1)
    horizontal = mid[None, :] + offsets[:, None] * vecs[:, -1][None, :]
    return np.column_stack([horizontal, np.full(len(offsets), (lo + hi) / 2)])


def _generic(predictor: Any, seed: int) -> LabelFn:
    def label(xyz: np.ndarray, rgb: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng(seed)
        keep = rng.choice(len(xyz), min(len(xyz), GENERIC_POINTS), replace=False)
        part = Scan(xyz[keep], None if rgb is None else rgb[keep])
        result = predictor.predict(part, seed=seed)
        return part.xyz, np.asarray(result.probs, dtype=np.float64)

    return label
