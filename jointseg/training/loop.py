"""Training RandLA-Net on several sources at once: folders of labelled scans, S3DIS's own
folder layout, synthetic rooms, each with a share of the crops.

Weighted cross-entropy (weights from the class mixture the crops have), Adam with exponential
decay, augmentation for other sensors (:mod:`jointseg.training.augment`),
class-balanced crop centres per source, batches built by worker processes
(:mod:`jointseg.training.batches`), neighbour searches on the GPU when training on one,
validation mIoU per source every epoch, resumable checkpoints with a model card, and the best
checkpoint by validation kept beside the last.

This module is the epochs and the time budget; the rest lives beside it: the run's model and
optimiser (:mod:`~jointseg.training.run_state`), its batches
(:mod:`~jointseg.training.streams`), one step (:mod:`~jointseg.training.step`),
validation (:mod:`~jointseg.training.validation`) and checkpoints
(:mod:`~jointseg.training.checkpoints`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from jointseg.network.randlanet.crops import Batch
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.training.batches import CropBatch
from jointseg.training.checkpoints import save_checkpoints
from jointseg.training.config import TrainConfig, TrainingData, training_data
from jointseg.training.run_state import TrainingRun, start_run
from jointseg.training.step import device_batch, train_mode, train_step
from jointseg.training.streams import bank_stream, crop_stream
from jointseg.training.validation import validate_sources

log = logging.getLogger(__name__)
STAGE = "train"


def train(
    cfg: TrainConfig, progress: ProgressFn | None = None, cancel: CancelToken | None = None
) -> Path:
    """Train, writing ``cfg.out`` after every epoch (with optimiser state, for ``resume``) and
    :func:`best_path` whenever the validation score is the best so far.

    Returns
    -------
    Path of the last checkpoint.
    """
    started = time.monotonic()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    cfg.out.parent.mkdir(parents=True, exist_ok=True)
    run = start_run(cfg)
    report(progress, STAGE, 0.0)
    data = training_data(cfg, run.model.config.grid_size)
    if cfg.init is not None:
        data.description += f"; started from {cfg.init.name}"
    stream = bank_stream(cfg, run, data) if cfg.bank is not None else crop_stream(cfg, run, data)
    loss_fn = torch.nn.CrossEntropyLoss(weight=data.loss_weights.to(run.device), ignore_index=-1)
    train_mode(run.model, cfg)
    with stream as batches:
        _train_epochs(cfg, run, loss_fn, batches, data, _Clock(cfg, started), (progress, cancel))
    return cfg.out


def _train_epochs(
    cfg: TrainConfig,
    run: TrainingRun,
    loss_fn: torch.nn.Module,
    batches: Iterator[Batch | CropBatch],
    data: TrainingData,
    clock: _Clock,
    hooks: tuple[ProgressFn | None, CancelToken | None],
) -> None:
    """The epochs from the run's start: steps on ``batches``, validation, checkpoints; within
    ``cfg.minutes`` when given (the last epoch cut short), a checkpoint every
    ``cfg.save_minutes`` besides the one after each epoch."""
    total_steps = cfg.epochs * cfg.steps_per_epoch
    progress, cancel = hooks
    for epoch in range(run.start_epoch, cfg.epochs):
        started, losses, hits, seen = time.perf_counter(), [], 0, 0
        for step in range(cfg.steps_per_epoch):
            check_cancel(cancel)
            loss, step_hits, step_seen = train_step(
                run, loss_fn, device_batch(next(batches), run), cfg
            )
            losses.append(loss)
            hits, seen = hits + step_hits, seen + step_seen
            report(progress, STAGE, (epoch * cfg.steps_per_epoch + step + 1) / total_steps)
            if clock.out_of_time():
                break
            if clock.save_due():
                save_checkpoints(cfg, run, data, epoch, validated=False)
                clock.saved()
        train_seconds = time.perf_counter() - started
        run.scheduler.step()
        miou, per_source = validate_sources(run.model, data.sources, cfg)
        run.history.append(
            {
                "epoch": epoch + 1,
                "loss": float(np.mean(losses)),
                "train_accuracy": hits / max(seen, 1),
                "val_miou": miou,
                "val_by_source": per_source,
                "seconds": time.perf_counter() - started,
                "steps_per_second": len(losses) / max(train_seconds, 1e-9),
            }
        )
        log.info(
            "epoch %d loss %.3f train accuracy %.3f val mIoU %s %s",
            epoch + 1, np.mean(losses), hits / max(seen, 1), miou, per_source,
        )  # fmt: skip
        save_checkpoints(cfg, run, data, epoch + 1)
        clock.saved()
        if clock.out_of_time():
            log.info("time budget of %s minutes spent after epoch %d", cfg.minutes, epoch + 1)
            break


class _Clock:
    """The run's time budget and the timed checkpoints."""

    def __init__(self, cfg: TrainConfig, started: float) -> None:
        self.start, self.last_save = started, time.monotonic()
        self.budget = None if cfg.minutes is None else 60.0 * cfg.minutes
        self.every = None if cfg.save_minutes is None else 60.0 * cfg.save_minutes

    def out_of_time(self) -> bool:
        return self.budget is not None and time.monotonic() - self.start >= self.budget

    def save_due(self) -> bool:
        return self.every is not None and time.monotonic() - self.last_save >= self.every

    def saved(self) -> None:
        self.last_save = time.monotonic()
