"""Fitting the network's head to users' corrections, without forgetting the rest.

Only the head learns (the body's features are fixed, :mod:`jointseg.adapt.features`): a few
thousand weights, so a few hundred steps on two cores take seconds and cannot wreck what the
body knows. Each step draws half its points from those a user corrected (cross-entropy to the
user's class, classes balanced) and half from the rest, where the head is held to the bundled
network's own answer (distillation): classes nobody corrected keep their labels.
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field
from torch import nn

from jointseg.classes import NUM_CLASSES
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report

log = logging.getLogger(__name__)
STAGE = "adapt"


class AdaptParams(BaseModel):
    """How the head learns; the defaults were chosen on the tuning scans (bench/adapt.py)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    steps: int = Field(300, ge=1, le=100_000)
    batch: int = Field(4096, ge=16)
    lr: float = Field(0.002, gt=0, le=1)
    keep_weight: float = Field(8.0, ge=0, description="weight of the distillation term")
    corrected_share: float = Field(
        0.5, gt=0, le=1, description="share of each step's points drawn from corrected points"
    )
    layers: int = Field(3, ge=1, le=3, description="the head's last layers that learn")
    replay_rooms: int = Field(
        4, ge=0, le=20, description="generated rooms whose points hold the head to the base"
    )
    keep_base_above: float | None = Field(
        None,
        gt=0,
        le=1,
        description="where the bundled head's top probability reaches this, its answer is "
        "kept (None: the adapted head everywhere)",
    )
    min_base_probability: float = Field(
        0.01,
        ge=0,
        lt=1,
        description="corrected points whose class the bundled network gives less than this "
        "are left out of the cross-entropy where they are a minority of their corrected segment "
        "(in a segment corrected whole, the points of another object; Examples.believable)",
    )
    seed: int = 0


@dataclass(frozen=True)
class Examples:
    """The head's training points, from every scan: features (M, C) float32, ``target`` (M,)
    the user's class or -1, ``teacher`` (M, K) the bundled network's probabilities, ``group``
    (M,) the corrected segment each corrected point was given its class in (ids unique over
    every scan; -1, or None for all, where unknown)."""

    features: np.ndarray
    target: np.ndarray
    teacher: np.ndarray
    group: np.ndarray | None = None

    @property
    def corrected(self) -> int:
        return int(np.count_nonzero(self.target >= 0))

    def believable(self, min_base_probability: float) -> np.ndarray:
        """(M,) bool: the corrected points to learn from.

        A segment corrected whole gives its class to every point it holds, also to those of
        another object (the chair's legs in a table's segment). The bundled network gives the
        user's class next to nothing at those: such points are left out when they are the
        minority of their corrected segment. Where most of a segment's points get next to
        nothing, the network is wrong about the segment itself (what corrections are for), and
        all of it counts; so does every point of a class the network gives next to nothing at
        most of its corrected points. Points of unknown segments count as one segment per
        class."""
        given = self.target >= 0
        if min_base_probability <= 0:
            return given
        rows = np.flatnonzero(given)
        cls = self.target[rows]
        low = self.teacher[rows, cls] < min_base_probability
        group = np.full(len(rows), -1) if self.group is None else self.group[rows]
        # per (segment, class) and per class: the share of points the network gives ~0
        mostly_low = _share((group + 1) * NUM_CLASSES + cls, low) >= 0.5
        class_low = _share(cls, low) >= 0.5
        keep = ~low | mostly_low | class_low
        out = np.zeros(len(self.target), bool)
        out[rows[keep]] = True
        return out


def _share(key: np.ndarray, flag: np.ndarray) -> np.ndarray:
    """Per element, the share of ``flag`` among the elements of its ``key``."""
    n = np.bincount(key)
    hits = np.bincount(key, weights=flag.astype(np.float64), minlength=len(n))
    return (hits / np.maximum(n, 1))[key]


def _class_weights(target: np.ndarray) -> torch.Tensor:
    """Inverse square-root frequency of the corrected classes, mean 1 over the points: a class
    corrected on a few segments still counts, without drowning the common ones."""
    counts = np.bincount(target, minlength=NUM_CLASSES).astype(np.float64)
    weights = np.where(counts > 0, 1.0 / np.sqrt(np.maximum(counts, 1)), 0.0)
    weights *= counts.sum() / max(float((weights * counts).sum()), 1e-12)
    return torch.as_tensor(weights, dtype=torch.float32)


def fit_head(
    head: nn.Module,
    examples: Examples,
    params: AdaptParams | None = None,
    *,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> tuple[nn.Module, list[float]]:
    """A copy of ``head`` fitted to ``examples``; the loss every step. The batch norms keep the
    statistics the body was trained with (eval mode, so dropout is off too)."""
    params = params or AdaptParams()
    if examples.corrected == 0:
        raise ValueError("no corrected points to learn from")
    fitted = copy.deepcopy(head).float().eval()
    learning = [m for m in fitted.children() if any(True for _ in m.parameters())]
    learning = learning[-params.layers :]
    for p in fitted.parameters():
        p.requires_grad_(False)
    for layer in learning:
        for p in layer.parameters():
            p.requires_grad_(True)
    rng = np.random.default_rng(params.seed)
    believable = examples.believable(params.min_base_probability)
    corrected = np.flatnonzero(believable)
    rest = np.flatnonzero(~believable)
    feats = torch.from_numpy(np.ascontiguousarray(examples.features, np.float32))
    target = torch.from_numpy(examples.target.astype(np.int64))
    teacher = torch.from_numpy(np.ascontiguousarray(examples.teacher, np.float32))
    ce = nn.CrossEntropyLoss(weight=_class_weights(examples.target[corrected]))
    optimiser = torch.optim.Adam([p for m in learning for p in m.parameters()], lr=params.lr)
    n_corr = max(1, int(round(params.batch * params.corrected_share)))
    n_rest = params.batch - n_corr if len(rest) else 0
    losses: list[float] = []
    with torch.enable_grad():
        for step in range(params.steps):
            check_cancel(cancel)
            pick = torch.from_numpy(rng.choice(corrected, n_corr))
            loss = ce(fitted(feats[pick]), target[pick])
            if n_rest and params.keep_weight > 0:
                keep = torch.from_numpy(rng.choice(rest, n_rest))
                log_p = torch.log_softmax(fitted(feats[keep]), dim=-1)
                kl = nn.functional.kl_div(log_p, teacher[keep], reduction="batchmean")
                loss = loss + params.keep_weight * kl
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            losses.append(float(loss.detach()))
            report(progress, STAGE, (step + 1) / params.steps)
    for p in fitted.parameters():
        p.requires_grad_(False)
    log.info("head fitted: %d steps, loss %.3f -> %.3f", params.steps, losses[0], losses[-1])
    return fitted, losses
