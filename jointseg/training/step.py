"""One training step: a batch on the training device, the weighted cross-entropy (with the
teacher's distillation when there is one), the optimiser's step; and the model's training mode."""

from __future__ import annotations

import numpy as np
import torch

from jointseg.classes import NUM_CLASSES
from jointseg.network.randlanet.crops import Batch
from jointseg.network.randlanet.knn import layer_indices
from jointseg.network.randlanet.model import RandLANet
from jointseg.training.batches import CropBatch
from jointseg.training.config import TrainConfig
from jointseg.training.run_state import TrainingRun


def train_mode(model: RandLANet, cfg: TrainConfig) -> None:
    """Training mode, with the batch norms held at their running statistics when
    ``cfg.freeze_norm``."""
    model.train()
    if cfg.freeze_norm:
        for module in model.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.eval()


def device_batch(item: Batch | CropBatch, run: TrainingRun) -> Batch:
    """A batch on the training device; crops sent without neighbours get them there."""
    if isinstance(item, Batch):
        return item.to(run.device, non_blocking=True)
    xyz = item.xyz.to(run.device, non_blocking=True)
    rgb = item.rgb.to(run.device, non_blocking=True)
    centred = xyz.clone()
    centred[:, :, :2] -= centred[:, :, :2].mean(dim=1, keepdim=True)
    coords, neighbours, pools, ups = layer_indices(centred, run.model.config)
    return Batch(
        torch.cat([centred, rgb], dim=2),
        coords,
        neighbours,
        pools,
        ups,
        np.empty((0, 0), dtype=np.int64),
        item.labels.to(run.device, non_blocking=True),
    )


def train_step(
    run: TrainingRun, loss_fn: torch.nn.Module, batch: Batch, cfg: TrainConfig
) -> tuple[float, int, int]:
    """One optimiser step: the loss, and the right and labelled points of the batch."""
    model, optimiser = run.model, run.optimiser
    logits = model(batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples)
    assert batch.labels is not None
    loss = loss_fn(logits.reshape(-1, NUM_CLASSES), batch.labels.reshape(-1))
    if run.teacher is not None:
        with torch.no_grad():
            taught = run.teacher(
                batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples
            )
        loss = (1 - cfg.distill_weight) * loss + cfg.distill_weight * distillation_loss(
            logits, taught, cfg.distill_temperature
        )
    optimiser.zero_grad()
    loss.backward()
    optimiser.step()
    known = batch.labels >= 0
    hits = int((logits.detach().argmax(-1) == batch.labels)[known].sum())
    return float(loss.detach()), hits, int(known.sum())


def distillation_loss(
    student: torch.Tensor, teacher: torch.Tensor, temperature: float
) -> torch.Tensor:
    """KL(teacher || student) of the outputs softened by ``temperature``, times its square
    (Hinton et al. 2015), so its gradients keep their scale whatever the temperature."""
    t = temperature
    log_p = torch.log_softmax(student.reshape(-1, NUM_CLASSES) / t, dim=-1)
    q = torch.softmax(teacher.reshape(-1, NUM_CLASSES) / t, dim=-1)
    return torch.nn.functional.kl_div(log_p, q, reduction="batchmean") * t * t
