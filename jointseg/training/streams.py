"""Where a run's batches come from: crops drawn from the sources as the run goes (worker
processes, :mod:`jointseg.training.batches`) or read from a crop bank
(:mod:`jointseg.training.bank`), started at the run's first step."""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import AbstractContextManager, nullcontext

from jointseg.network.batches import Prefetcher
from jointseg.network.randlanet.crops import Batch
from jointseg.training.bank_batches import BankBatches, check_bank
from jointseg.training.batches import BatchMaker, CropBatch, batch_stream
from jointseg.training.config import TrainConfig, TrainingData
from jointseg.training.run_state import TrainingRun

log = logging.getLogger(__name__)


def default_workers() -> int:
    """Batch-building processes by default: one per core beside the training process, at most
    8 (on a GPU machine the batches are the bottleneck; on two cores one worker)."""
    return max(0, min(8, len(os.sched_getaffinity(0)) - 1))


def crop_stream(
    cfg: TrainConfig, run: TrainingRun, data: TrainingData
) -> AbstractContextManager[Iterator[Batch | CropBatch]]:
    """Batches of crops drawn from the sources as the run goes (by workers or a thread)."""
    on_device = (
        cfg.neighbours_on_device
        if cfg.neighbours_on_device is not None
        else run.device.type == "cuda"
    )
    maker = BatchMaker(
        clouds=data.clouds,
        draw_p=data.draw_p,
        centre_p=data.centre_p,
        model_config=run.model.config,
        aug=cfg.augmentation(),
        batch_size=cfg.batch_size,
        num_points=cfg.num_points,
        seed=cfg.seed,
        first=run.start_epoch * cfg.steps_per_epoch,
        count=(cfg.epochs - run.start_epoch) * cfg.steps_per_epoch,
        neighbours_on_device=on_device,
    )
    return batch_stream(
        maker, workers=cfg.workers, prefetch=cfg.prefetch, pin=run.device.type == "cuda"
    )


def bank_stream(
    cfg: TrainConfig, run: TrainingRun, data: TrainingData
) -> AbstractContextManager[Iterator[Batch]]:
    """Batches read from the crop bank (built or extended first when ``cfg.bank_crops``);
    reading is cheap, so in this process, a step ahead in a thread."""
    from jointseg.training.bank import CropBank, build_bank

    assert cfg.bank is not None
    if cfg.bank_crops is not None:
        workers = cfg.bank_workers
        build_bank(
            cfg.model_copy(update={"colour": True}) if not cfg.colour else cfg,
            cfg.bank,
            cfg.bank_crops,
            max_bytes=int(cfg.bank_gb * 1e9),
            workers=len(os.sched_getaffinity(0)) if workers is None else workers,
            data=data if cfg.colour else None,
        )
    bank = CropBank(cfg.bank)
    check_bank(bank, run.model.config, cfg.num_points, cfg.colour)
    if bank.spec.sources != cfg.sources():
        log.warning(
            "crop bank %s was drawn from %s, this run names %s (validation and loss weights "
            "follow the run's)", cfg.bank, bank.spec.sources, cfg.sources(),
        )  # fmt: skip
    data.bank = {**bank.manifest.summary(cfg.bank), "step_augment": cfg.step_augment.model_dump()}
    data.description += f"; crops from the bank {cfg.bank} ({len(bank)} crops)"
    aug = cfg.step_augment.model_copy(update={"colour_drop": cfg.augmentation().colour_drop})
    batches = BankBatches(
        bank,
        cfg.batch_size,
        cfg.seed,
        aug,
        colour=cfg.colour,
        first=run.start_epoch * cfg.steps_per_epoch,
        count=(cfg.epochs - run.start_epoch) * cfg.steps_per_epoch,
    )
    items = (batches[i] for i in range(len(batches)))
    return Prefetcher(items) if cfg.prefetch else nullcontext(items)
