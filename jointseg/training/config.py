"""What a training run is told and what it draws from: :class:`TrainConfig` (validated once, at
the edge) and :func:`training_data` (the sources loaded, their draw and centre probabilities and
the loss weights). Apart from the loop, so that the crop bank can load the same data without
importing the loop that trains from it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator

from jointseg.classes import NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.network.randlanet.crops import GridCloud
from jointseg.network.randlanet.model import RandLANetConfig
from jointseg.training.augment import AugmentParams, StepAugment
from jointseg.training.data import centre_weights
from jointseg.training.sources import (
    Source,
    SourceOptions,
    load_sources,
    parse_source,
)


class TrainConfig(BaseModel):
    """Everything a training run needs; stored in the checkpoint's model card."""

    model_config = ConfigDict(extra="forbid")

    data: list[str] = Field(
        default_factory=lambda: ["synth"],
        description="sources, each '[NAME=]PATH[:SHARE]' or 'synth[:SHARE]': a folder of "
        "labelled scans or a Stanford3dDataset_v1.2 folder (see jointseg.training.sources)",
    )
    out: Path
    test_area: int = Field(5, ge=1, le=6, description="S3DIS area held out for validation")
    synth_rooms: int = Field(40, ge=1, description="synthetic training rooms")
    synth_floors: int = Field(4, ge=0, description="synthetic training floors")
    synth_points: int = Field(300_000, ge=10_000, description="points per synthetic room")
    val_rooms: int = Field(4, ge=0, description="synthetic validation rooms")
    val_scans: list[str] = Field(
        default_factory=list,
        description="folder data: file stems (or fnmatch patterns, e.g. 'scene0002_*' for every "
        "re-scan of a room) kept out of training for validation",
    )
    val_count: int = Field(
        5, ge=1, description="folder data without val_scans: this many, in a name-hash order"
    )
    exclude_scans: list[str] = Field(
        default_factory=list,
        description="folder data: file stems or patterns kept out of training and validation "
        "alike (scans kept to judge the result)",
    )
    synth_share: float = Field(
        0.0,
        ge=0,
        lt=1,
        description="share of crops from synthetic rooms (the same as adding 'synth:SHARE')",
    )
    balanced_crops: bool = Field(True, description="centre crops on rare classes more often")
    init: Path | None = Field(None, description="start from these weights (fresh optimiser)")
    epochs: int = Field(20, ge=1)
    steps_per_epoch: int = Field(100, ge=1)
    batch_size: int = Field(2, ge=1)
    num_points: int = Field(16_384, ge=1024, description="points per training crop")
    lr: float = Field(0.01, gt=0)
    gamma: float = Field(0.95, gt=0, le=1, description="learning-rate decay per epoch")
    seed: int = 0
    resume: Path | None = None
    threads: int | None = None
    num_channels_scale: float = Field(
        1.0, gt=0, le=1, description="scale RandLA-Net's channel widths (lighter network)"
    )
    freeze_norm: bool = Field(
        False,
        description="keep the batch norms' running statistics and train through them: "
        "fine-tuning a trained network on small batches of small crops otherwise replaces "
        "statistics learnt on whole crops (a CPU run from the bundled weights fell from 0.41 "
        "to 0.02 validation mIoU in 52 steps)",
    )
    elastic: float = Field(
        0.3, ge=0, le=1, description="share of training crops given an elastic distortion"
    )
    augment: AugmentParams = Field(
        default_factory=AugmentParams,
        description="density, partial-room, slice, tilt and colour augmentation",
    )
    colour: bool = Field(
        True,
        description="feed the scans' colour; False trains a colour-free network (colour inputs "
        "held at zero in every crop, training and validation), for LiDAR-only scans",
    )
    prefetch: bool = Field(
        True,
        description="without workers: build the next batch in a background thread while the "
        "network runs",
    )
    workers: int = Field(
        0,
        ge=0,
        le=64,
        description="processes building batches (0: in the training process); the batches "
        "are the same for any number",
    )
    neighbours_on_device: bool | None = Field(
        None,
        description="run the per-layer neighbour searches on the training device (default: "
        "on CUDA devices, where they are faster than the workers' KD-trees)",
    )
    device: str | None = Field(None, description="'cpu' or 'cuda' (default: cuda when present)")
    minutes: float | None = Field(
        None,
        gt=0,
        description="stop stepping this many minutes after the run started (data loading "
        "included); the epoch is then validated and written",
    )
    save_minutes: float | None = Field(
        None, gt=0, description="also write the checkpoint this often within an epoch"
    )
    packed_copy: Path | None = Field(
        None, description="after every checkpoint, a packed copy (float16, gzip) here"
    )
    teacher: Path | None = Field(
        None,
        description="distil from these weights: the loss adds the KL divergence to the "
        "teacher's softened outputs on the same crops",
    )
    distill_weight: float = Field(0.5, ge=0, le=1, description="the teacher's share of the loss")
    distill_temperature: float = Field(2.0, gt=0)
    sliced_init: Path | None = Field(
        None,
        description="start a narrower network from the leading channels of these weights",
    )
    command: str | None = Field(
        None, description="the command line that started the run, kept in the model card"
    )
    bank: Path | None = Field(
        None,
        description="train on the crops of this crop bank (jointseg.training.bank): "
        "crops and their neighbour indices drawn once, read per step, with step_augment",
    )
    bank_crops: int | None = Field(
        None, ge=1, description="first build or extend the bank to this many crops"
    )
    bank_gb: float = Field(4.0, gt=0, description="the bank's bound on disk (GB)")
    bank_workers: int | None = Field(
        None, ge=0, le=64, description="processes building the bank (default: one per core)"
    )
    step_augment: StepAugment = Field(
        default_factory=StepAugment,
        description="augmentation drawn per step on bank crops (none changes a neighbour)",
    )

    @field_validator("data", mode="before")
    @classmethod
    def _one_or_many(cls, value: object) -> object:
        """A single source (as older cards store it) is a list of one."""
        return [value] if isinstance(value, str) else value

    def sources(self) -> list[str]:
        """The source specs, with ``synth_share`` as a synthetic source when none is named."""
        specs = list(self.data)
        if self.synth_share > 0 and not any(parse_source(s).is_synth for s in specs):
            real = [parse_source(s) for s in specs]
            if any(r.share is not None for r in real):
                raise ConfigError("give synth a share with --data synth:SHARE, not synth_share")
            specs = [f"{r.name}={r.path}:{(1 - self.synth_share) / len(real):.6g}" for r in real]
            specs.append(f"synth:{self.synth_share:.6g}")
        return specs

    def augmentation(self) -> AugmentParams:
        """The augmentation settings, ``elastic`` included (no colour at all for a colour-free
        network)."""
        update: dict[str, object] = {"elastic": self.elastic}
        if not self.colour:
            update["colour_drop"] = 1.0
        return self.augment.model_copy(update=update)


def model_config(cfg: TrainConfig) -> RandLANetConfig:
    """The official configuration, channel widths scaled by ``num_channels_scale``."""
    base = RandLANetConfig(num_points=cfg.num_points)
    if cfg.num_channels_scale == 1.0:
        return base
    scale = cfg.num_channels_scale
    return base.model_copy(
        update={
            "d_stem": max(4, round(base.d_stem * scale)),
            "d_out": tuple(max(8, round(d * scale)) for d in base.d_out),
        }
    )


def weights_from_frequency(freq: np.ndarray) -> torch.Tensor:
    """RandLA-Net's weights 1 / (frequency + 0.02), so rare classes are not ignored."""
    return torch.tensor(1.0 / (np.asarray(freq) + 0.02), dtype=torch.float32)


def class_weights(labels: list[np.ndarray]) -> torch.Tensor:
    """:func:`weights_from_frequency` of the labels' class frequencies (-1 left out)."""
    counts = np.bincount(np.concatenate([lab[lab >= 0] for lab in labels]), minlength=NUM_CLASSES)
    return weights_from_frequency(counts / max(counts.sum(), 1))


def source_options(cfg: TrainConfig, grid: float) -> SourceOptions:
    """How :func:`load_sources` reads the configuration's sources."""
    return SourceOptions(
        grid=grid,
        val_patterns=list(cfg.val_scans),
        exclude_patterns=list(cfg.exclude_scans),
        val_count=cfg.val_count,
        test_area=cfg.test_area,
        synth_rooms=cfg.synth_rooms,
        synth_floors=cfg.synth_floors,
        synth_val_rooms=cfg.val_rooms,
        synth_points=cfg.synth_points,
    )


@dataclass
class TrainingData:
    """What the steps draw from: every source's clouds, their draw and centre probabilities, and
    the loss weights of the mixture."""

    sources: list[Source]
    clouds: list[GridCloud]
    draw_p: np.ndarray
    centre_p: list[np.ndarray | None]
    loss_weights: torch.Tensor
    description: str
    bank: dict | None = None  # the bank's summary for the model card


def training_data(cfg: TrainConfig, grid: float) -> TrainingData:
    """Load the sources; class statistics per source: crop centres are balanced within each
    source, and the loss weights follow the class mixture the crops actually have."""
    sources = load_sources(cfg.sources(), source_options(cfg, grid))
    if not cfg.colour:
        for src in sources:
            src.train = [without_colour(c) for c in src.train]
            src.val = [without_colour(c) for c in src.val]
    clouds: list[GridCloud] = []
    draw: list[float] = []
    centre_p: list[np.ndarray | None] = []
    mixture = np.zeros(NUM_CLASSES)
    for src in sources:
        freq = src.class_frequency
        mixture += src.share * freq
        weights = weights_from_frequency(freq).numpy()
        for cloud in src.train:
            clouds.append(cloud)
            draw.append(src.share / len(src.train))
            assert cloud.labels is not None
            centre_p.append(centre_weights(cloud.labels, weights) if cfg.balanced_crops else None)
    text = "; ".join(f"{s.spec.name} ({s.share:.0%} of crops): {s.description}" for s in sources)
    draw_p = np.asarray(draw) / np.sum(draw)
    return TrainingData(sources, clouds, draw_p, centre_p, weights_from_frequency(mixture), text)


def without_colour(cloud: GridCloud) -> GridCloud:
    """The cloud as a colour-free network sees it: colour inputs at zero, as for a scan that
    has none."""
    return replace(cloud, rgb=np.zeros_like(cloud.rgb))
