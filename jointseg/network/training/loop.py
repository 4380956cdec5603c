"""Training RandLA-Net on several sources at once: folders of labelled scans, S3DIS's own
folder layout, synthetic rooms, each with a share of the crops.

Weighted cross-entropy (weights from the class mixture the crops have), Adam with exponential
decay, augmentation for other sensors (:mod:`jointseg.network.training.augment`),
class-balanced crop centres per source, batches built by worker processes
(:mod:`jointseg.network.training.batches`), neighbour searches on the GPU when training on one,
validation mIoU per source every epoch, resumable checkpoints with a model card, and the best
checkpoint by validation kept beside the last.
"""

from __future__ import annotations

import logging
import os
import platform
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import torch

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.metrics import evaluate
from jointseg.network.base import pick_device
from jointseg.network.batches import Prefetcher
from jointseg.network.randlanet.checkpoint import load_checkpoint, save_checkpoint
from jointseg.network.randlanet.crops import (
    MIN_CROP,
    Batch,
    GridCloud,
    build_batch,
    crop_indices,
    pad_to,
)
from jointseg.network.randlanet.knn import layer_indices
from jointseg.network.randlanet.model import RandLANet
from jointseg.network.randlanet.slicing import sliced_init
from jointseg.network.training.bank_batches import BankBatches, check_bank
from jointseg.network.training.batches import BatchMaker, CropBatch, batch_stream
from jointseg.network.training.config import (
    TrainConfig,
    TrainingData,
    model_config,
    training_data,
)
from jointseg.network.training.sources import (
    S3DIS_TERMS,
    SCANNET_TERMS,
    SYNTH_TERMS,
    Source,
    parse_source,
    resolve_shares,
    terms_for,
)
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report

__all__ = ["S3DIS_TERMS", "SCANNET_TERMS", "SYNTH_TERMS", "TrainConfig", "train"]

log = logging.getLogger(__name__)
STAGE = "train"


def validation_crop(cloud: GridCloud, num_points: int, rng: np.random.Generator):
    """A crop of the validation cloud around a random point, as inference sees it."""
    centre = rng.integers(len(cloud.xyz))
    idx = crop_indices(cloud, cloud.xyz[centre], num_points)
    idx = rng.permutation(pad_to(idx, min(num_points, max(len(idx), MIN_CROP)), rng))
    assert cloud.labels is not None
    return cloud.xyz[idx], cloud.rgb[idx], cloud.labels[idx], idx


def train_mode(model: RandLANet, cfg: TrainConfig) -> None:
    """Training mode, with the batch norms held at their running statistics when
    ``cfg.freeze_norm``."""
    model.train()
    if cfg.freeze_norm:
        for module in model.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.eval()


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


def default_workers() -> int:
    """Batch-building processes by default: one per core beside the training process, at most
    8 (on a GPU machine the batches are the bottleneck; on two cores one worker)."""
    return max(0, min(8, len(os.sched_getaffinity(0)) - 1))


def best_path(out: Path) -> Path:
    """Where the best checkpoint by validation is kept, beside the last one."""
    return out.with_name(f"{out.stem}.best{out.suffix}")


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
    run = _start(cfg)
    report(progress, STAGE, 0.0)
    data = training_data(cfg, run.model.config.grid_size)
    if cfg.init is not None:
        data.description += f"; started from {cfg.init.name}"
    stream = _bank_stream(cfg, run, data) if cfg.bank is not None else _crop_stream(cfg, run, data)
    loss_fn = torch.nn.CrossEntropyLoss(weight=data.loss_weights.to(run.device), ignore_index=-1)
    train_mode(run.model, cfg)
    with stream as batches:
        _train_epochs(cfg, run, loss_fn, batches, data, _Clock(cfg, started), (progress, cancel))
    return cfg.out


def _crop_stream(
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


def _bank_stream(
    cfg: TrainConfig, run: TrainingRun, data: TrainingData
) -> AbstractContextManager[Iterator[Batch]]:
    """Batches read from the crop bank (built or extended first when ``cfg.bank_crops``);
    reading is cheap, so in this process, a step ahead in a thread."""
    from jointseg.network.training.bank import CropBank, build_bank

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


def _start(cfg: TrainConfig) -> TrainingRun:
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


def card_facts(cfg: TrainConfig, history: list[dict]) -> dict[str, object]:
    """What a user deciding whether to trust the weights wants: the hardware, the command, the
    validation figures and the data's terms of use."""
    scores = [(h["val_miou"], h["epoch"]) for h in history if h.get("val_miou") is not None]
    best = max(scores) if scores else None
    specs = [parse_source(s) for s in cfg.sources()]
    shares = resolve_shares(specs)
    real = any(not s.is_synth for s in specs)
    device = pick_device(cfg.device)
    gpu = torch.cuda.get_device_name(device) if device.type == "cuda" else "no GPU"
    terms = list(dict.fromkeys(terms_for(s) for s in specs))
    return {
        "hardware": (
            f"{platform.machine()} CPU, {os.cpu_count()} cores, torch {torch.__version__}, "
            f"{torch.get_num_threads()} torch threads, {gpu}"
        ),
        "command": cfg.command,
        "validation": {
            "last_miou": scores[-1][0] if scores else None,
            "best_miou": best[0] if best else None,
            "best_epoch": best[1] if best else None,
            "what": "mean over the real sources of mIoU on random crops of their held-out "
            "scans (per source in the history's val_by_source)"
            if real
            else "mIoU on random crops of held-out synthetic rooms",
        },
        "sources": {s.name: round(share, 4) for s, share in zip(specs, shares, strict=True)},
        "synthetic_share": sum(share for s, share in zip(specs, shares, strict=True) if s.is_synth),
        "terms": "; ".join(terms),
    }


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
            loss, step_hits, step_seen = _step(run, loss_fn, device_batch(next(batches), run), cfg)
            losses.append(loss)
            hits, seen = hits + step_hits, seen + step_seen
            report(progress, STAGE, (epoch * cfg.steps_per_epoch + step + 1) / total_steps)
            if clock.out_of_time():
                break
            if clock.save_due():
                _save(cfg, run, data, epoch, validated=False)
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
        _save(cfg, run, data, epoch + 1)
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


def _step(
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


def _save(
    cfg: TrainConfig, run: TrainingRun, data: TrainingData, epochs: int, *, validated: bool = True
) -> None:
    """The last checkpoint, and the best one when this epoch's validation is the best yet (a
    timed save within an epoch, ``validated=False``, only the last); packed copies of both
    when ``cfg.packed_copy`` is set."""
    card = {
        "architecture": "RandLA-Net (Hu et al. 2020), S3DIS configuration",
        "classes": list(CLASS_NAMES),
        "data": data.description,
        "class_frequency": {
            s.spec.name: [round(float(f), 5) for f in s.class_frequency] for s in data.sources
        },
        "epochs": epochs,
        "steps": epochs * cfg.steps_per_epoch,
        "history": run.history,
        "train_config": cfg.model_dump(mode="json"),
        "colour": cfg.colour,
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        **card_facts(cfg, run.history),
    }
    if data.bank is not None:
        card["bank"] = data.bank
    extra = {
        "optimizer": run.optimiser.state_dict(),
        "scheduler": run.scheduler.state_dict(),
        "epoch": epochs,
    }
    save_checkpoint(cfg.out, run.model, card, extra=extra)
    packed = {**card, "weights_dtype": "float16"}
    if cfg.packed_copy is not None:
        save_checkpoint(cfg.packed_copy, run.model, packed, half=True, compress=True)
    scores = [h["val_miou"] for h in run.history if h.get("val_miou") is not None]
    latest = run.history[-1].get("val_miou") if validated and run.history else None
    if latest is not None and latest >= max(scores):
        save_checkpoint(best_path(cfg.out), run.model, {**card, "best_of_run": True}, extra=extra)
        if cfg.packed_copy is not None:
            best = {**packed, "best_of_run": True}
            save_checkpoint(best_path(cfg.packed_copy), run.model, best, half=True, compress=True)
