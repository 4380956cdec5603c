"""A run's checkpoints: the last one after every epoch (with the optimiser's state, for
``resume``), the best by validation beside it, packed copies of both, and the model card that
tells a user whether to trust the weights."""

from __future__ import annotations

import os
import platform
from datetime import UTC, datetime
from pathlib import Path

import torch

from jointseg.classes import CLASS_NAMES
from jointseg.network.base import pick_device
from jointseg.network.randlanet.checkpoint import save_checkpoint
from jointseg.training.config import TrainConfig, TrainingData
from jointseg.training.run_state import TrainingRun
from jointseg.training.sources import parse_source, resolve_shares, terms_for


def best_path(out: Path) -> Path:
    """Where the best checkpoint by validation is kept, beside the last one."""
    return out.with_name(f"{out.stem}.best{out.suffix}")


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


def save_checkpoints(
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
