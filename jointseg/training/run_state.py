"""What a training run holds: the model (fresh, initialised from weights, or resumed from a
checkpoint), Adam with exponential learning-rate decay, the epoch it starts at, its history so
far and the teacher of a distilled run, on the training device."""

from __future__ import annotations

from dataclasses import dataclass

import torch

from jointseg.exceptions import ConfigError
from jointseg.network.base import pick_device
from jointseg.network.randlanet.checkpoint import load_checkpoint
from jointseg.network.randlanet.model import RandLANet
from jointseg.network.randlanet.slicing import sliced_init
from jointseg.training.config import TrainConfig, model_config


@dataclass
class TrainingRun:
    """The model and optimiser of a run, where it starts and what it has recorded so far."""

    model: RandLANet
    device: torch.device
    optimiser: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    start_epoch: int
    history: list[dict]
    teacher: RandLANet | None = None


def start_run(cfg: TrainConfig) -> TrainingRun:
    """A fresh, initialised or resumed model with its optimiser, on the training device."""
    history: list[dict] = []
    start_epoch = 0
    body: dict | None = None
    if cfg.resume is not None:
        model, card, body = load_checkpoint(cfg.resume)
        # A packed checkpoint (models pack) has no optimiser state or epoch: continue its
        # weights from the epoch its card records, with a fresh optimiser.
        start_epoch = int(body.get("epoch", card.get("epochs", 0)))
        history = list(card.get("history", []))
    elif cfg.init is not None:
        model, _, _ = load_checkpoint(cfg.init)
    else:
        model = RandLANet(model_config(cfg))
        if cfg.sliced_init is not None:
            sliced_init(model, load_checkpoint(cfg.sliced_init)[0])
    device = pick_device(cfg.device)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"device {cfg.device!r}: this machine's torch sees no CUDA device")
    model.to(device)
    optimiser = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    scheduler = torch.optim.lr_scheduler.ExponentialLR(optimiser, cfg.gamma)
    if body is not None and "optimizer" in body:
        optimiser.load_state_dict(body["optimizer"])
        scheduler.load_state_dict(body["scheduler"])
    teacher = None
    if cfg.teacher is not None:
        teacher = load_checkpoint(cfg.teacher)[0].to(device).eval()
        for p in teacher.parameters():
            p.requires_grad_(False)
    return TrainingRun(model, device, optimiser, scheduler, start_epoch, history, teacher)
