"""Validation during training: mIoU on deterministic crops of each source's held-out scans,
and the score that picks the best checkpoint (the mean over the real sources)."""

from __future__ import annotations

import numpy as np
import torch

from jointseg.metrics import evaluate
from jointseg.network.randlanet.crops import MIN_CROP, GridCloud, build_batch, crop_indices, pad_to
from jointseg.network.randlanet.model import RandLANet
from jointseg.training.config import TrainConfig
from jointseg.training.sources import Source
from jointseg.training.step import train_mode


def validation_crop(cloud: GridCloud, num_points: int, rng: np.random.Generator):
    """A crop of the validation cloud around a random point, as inference sees it."""
    centre = rng.integers(len(cloud.xyz))
    idx = crop_indices(cloud, cloud.xyz[centre], num_points)
    idx = rng.permutation(pad_to(idx, min(num_points, max(len(idx), MIN_CROP)), rng))
    assert cloud.labels is not None
    return cloud.xyz[idx], cloud.rgb[idx], cloud.labels[idx], idx


def validate(model: RandLANet, clouds: list[GridCloud], cfg: TrainConfig) -> float | None:
    """mIoU on deterministic crops of each validation cloud (about twice its points)."""
    if not clouds:
        return None
    rng = np.random.default_rng(12345)
    gts, preds = [], []
    device = next(model.parameters()).device
    model.eval()
    with torch.no_grad():
        for cloud in clouds:
            for _ in range(max(2, int(np.ceil(2 * len(cloud.xyz) / cfg.num_points)))):
                xyz, rgb, lab, idx = validation_crop(cloud, cfg.num_points, rng)
                batch = build_batch([(xyz, rgb, lab, idx)], model.config).to(device)
                logits = model(
                    batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples
                )
                preds.append(logits.argmax(-1).cpu().numpy().ravel())
                gts.append(lab)
    train_mode(model, cfg)
    return evaluate(np.concatenate(gts), np.concatenate(preds)).miou


def validate_sources(
    model: RandLANet, sources: list[Source], cfg: TrainConfig
) -> tuple[float | None, dict[str, float | None]]:
    """Validation mIoU per source, and the score that picks the best checkpoint: the mean over
    the real sources that have validation scans (over synth when there is no real one)."""
    per = {s.spec.name: validate(model, s.val, cfg) for s in sources}
    real = [per[s.spec.name] for s in sources if not s.spec.is_synth]
    pool = [v for v in real if v is not None] or [v for v in per.values() if v is not None]
    return (float(np.mean(pool)) if pool else None), per
