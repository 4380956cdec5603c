"""Shippable weights: a training checkpoint packed (weights and card, float16, gzip) or two
fine-tunes blended, with the card facts that training records
(:func:`jointseg.training.checkpoints.card_facts`)."""

from __future__ import annotations

import os
from pathlib import Path

from jointseg.exceptions import ConfigError
from jointseg.network.randlanet.checkpoint import load_checkpoint, save_checkpoint
from jointseg.network.randlanet.model import RandLANet
from jointseg.training.checkpoints import card_facts
from jointseg.training.config import TrainConfig


def pack_checkpoint(
    source: str | os.PathLike[str],
    target: str | os.PathLike[str],
    *,
    half: bool = True,
    command: str | None = None,
) -> Path:
    """Write a shippable copy of a training checkpoint: weights and card only, no optimiser or
    scheduler state, float16 weights by default (halves the size; predictions barely move),
    gzip-compressed.

    Raises
    ------
    ConfigError
        When ``source`` is not a jointseg checkpoint.
    """
    model, card, body = load_checkpoint(source)
    if "train_config" in card:  # cards written before these facts existed get them now
        facts = card_facts(
            TrainConfig.model_validate(card["train_config"]), list(card.get("history", []))
        )
        if "hardware" not in card:
            facts["hardware"] = f"{facts['hardware']} (recorded when packed)"
        card = {**facts, **{k: v for k, v in card.items() if v is not None}}
    if command and not card.get("command"):
        card["command"] = command
    return _save_packed(target, model, card, half=half)


def _save_packed(
    target: str | os.PathLike[str], model: RandLANet, card: dict, *, half: bool
) -> Path:
    """Weights and card only, gzip-compressed; the card states the weights' dtype, and its input
    conventions are the ones :func:`save_checkpoint` writes now."""
    card = {**card, "weights_dtype": "float16" if half else "float32"}
    card.pop("input_conventions", None)
    Path(target).parent.mkdir(parents=True, exist_ok=True)
    save_checkpoint(Path(target), model, card, half=half, compress=True)
    return Path(target)


def blend_checkpoints(
    base: str | os.PathLike[str],
    tuned: str | os.PathLike[str],
    weight: float,
    target: str | os.PathLike[str],
) -> Path:
    """Weights ``(1 - weight) * base + weight * tuned`` (a weight-space ensemble of a network
    and its fine-tuned copy, Wortsman et al. 2022), packed like :func:`pack_checkpoint`.

    Why: fine-tuning on new sensors trades accuracy on the old ones; the blend keeps most of
    both. The card is the tuned one's, with the blend recorded.

    Raises
    ------
    ConfigError
        When the weight is outside [0, 1] or the two networks differ in shape.
    """
    if not 0 <= weight <= 1:
        raise ConfigError(f"blend weight must be in [0, 1], got {weight}")
    first, base_card, _ = load_checkpoint(base)
    model, card, _ = load_checkpoint(tuned)
    if first.config != model.config:
        raise ConfigError(f"{base} and {tuned} are different networks: cannot blend them")
    a, b = first.state_dict(), model.state_dict()
    blended = {
        k: (a[k].float() * (1 - weight) + b[k].float() * weight).to(b[k].dtype)
        if b[k].is_floating_point()
        else b[k]
        for k in b
    }
    model.load_state_dict(blended)
    card = {
        **card,
        "blend": {
            "base": Path(base).name,
            "base_data": base_card.get("data"),
            "tuned": Path(tuned).name,
            "weight_of_tuned": weight,
            "what": "weights (1 - w) * base + w * tuned, w = weight_of_tuned",
        },
    }
    return _save_packed(target, model, card, half=True)
