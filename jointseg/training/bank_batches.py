"""Training batches read from a crop bank (:mod:`jointseg.training.bank`).

A batch is B bank crops, stacked, with augmentations drawn per step that leave every layer's
neighbours as they are, so the stored indices stay right: a rotation about the vertical axis, a
mirror, a uniform scale (distances all scaled alike keep their order), colour gain, offset and
drops (colour is no part of the search). Batch ``i`` draws its crops and augmentation from a
generator seeded with ``(seed, i)``, as the trainer's batches do, so a resumed run continues
with the batches it would have drawn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from jointseg.exceptions import ConfigError
from jointseg.network.randlanet.crops import Batch
from jointseg.network.randlanet.model import RandLANetConfig
from jointseg.training.augment import StepAugment
from jointseg.training.bank import CropBank, layer_sizes


def check_bank(bank: CropBank, model: RandLANetConfig, num_points: int, colour: bool) -> None:
    """Refuse a bank whose crops do not fit the network or the run."""
    spec = bank.spec
    if (spec.ratios, spec.k) != (model.ratios, model.k) or spec.grid != model.grid_size:
        raise ConfigError(
            f"crop bank {bank.folder}: layers {spec.ratios}, k {spec.k}, grid {spec.grid} do "
            f"not match the network's {model.ratios}, k {model.k}, grid {model.grid_size}"
        )
    if spec.num_points != num_points:
        raise ConfigError(
            f"crop bank {bank.folder} holds crops of {spec.num_points} points, the run asks "
            f"for {num_points}: give --num-points {spec.num_points}"
        )
    if colour and not spec.colour:
        raise ConfigError(
            f"crop bank {bank.folder} was drawn without colour: it cannot train a colour "
            "network (a colour bank serves a colour-free run, its colour held at zero)"
        )


def augment_xyz(xyz: np.ndarray, rng: np.random.Generator, aug: StepAugment) -> np.ndarray:
    """A crop's centred points rotated about z, mirrored and scaled: an isometry times a
    scalar, so every point keeps its nearest neighbours."""
    theta = rng.uniform(0, 2 * np.pi) if aug.rotate else 0.0
    c, s = np.cos(theta), np.sin(theta)
    m = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    if rng.random() < aug.mirror:
        m = m @ np.diag([-1.0, 1.0, 1.0])
    m *= rng.uniform(*aug.scale)
    return (xyz @ m.T.astype(np.float32)).astype(np.float32)


def augment_rgb(rgb: np.ndarray, rng: np.random.Generator, aug: StepAugment) -> np.ndarray:
    """Colour gain and offset per channel, or no colour at all; crops without colour stay so."""
    if rng.random() < aug.colour_drop or not rgb.any():
        return np.zeros_like(rgb)
    gain = rng.uniform(1 - aug.gain, 1 + aug.gain, 3)
    offset = rng.uniform(-aug.offset, aug.offset, 3)
    return np.clip(rgb * gain + offset, 0, 1).astype(np.float32)


def bank_batch(
    records: list[np.void],
    sizes: list[int],
    rng: np.random.Generator | None,
    aug: StepAugment,
    *,
    colour: bool = True,
) -> Batch:
    """Network inputs of the crops, as ``build_batch`` would give them (``rng`` None: no
    augmentation); ``colour`` False holds the colour at zero."""
    xyz, rgb = [], []
    for rec in records:
        pts = np.array(rec["xyz"], dtype=np.float32)
        pts[:, :2] -= pts[:, :2].mean(axis=0)  # as build_batch centres a crop
        col = np.asarray(rec["rgb"], dtype=np.float32)
        if not colour:
            col = np.zeros_like(col)
        if rng is not None:
            pts, col = augment_xyz(pts, rng, aug), augment_rgb(col, rng, aug)
        xyz.append(pts)
        rgb.append(col)
    points = np.stack(xyz)
    nb = np.stack([rec["neighbours"] for rec in records]).astype(np.int64)
    up = np.stack([rec["upsamples"] for rec in records]).astype(np.int64)
    coords, neighbours, pools, ups = [], [], [], []
    start = 0
    for n, keep in zip(sizes[:-1], sizes[1:], strict=True):
        coords.append(torch.from_numpy(np.ascontiguousarray(points[:, :n])))
        layer = torch.from_numpy(np.ascontiguousarray(nb[:, start : start + n]))
        neighbours.append(layer)
        pools.append(layer[:, :keep].contiguous())
        ups.append(torch.from_numpy(np.ascontiguousarray(up[:, start : start + n, None])))
        start += n
    labels = np.stack([rec["labels"] for rec in records]).astype(np.int64)
    return Batch(
        torch.from_numpy(np.concatenate([points, np.stack(rgb)], axis=2)),
        coords,
        neighbours,
        pools,
        ups,
        np.tile(np.arange(points.shape[1]), (len(records), 1)),
        torch.from_numpy(labels),
    )


@dataclass
class BankBatches:
    """Batch ``i`` of a run from a bank: ``batch_size`` distinct crops drawn with ``(seed, i)``."""

    bank: CropBank
    batch_size: int
    seed: int
    aug: StepAugment
    colour: bool = True
    first: int = 0  # the global index of item 0 (resumed runs)
    count: int = 0

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, item: int) -> Batch:
        rng = np.random.default_rng([self.seed, self.first + item])
        size = min(self.batch_size, len(self.bank))
        picks = rng.choice(len(self.bank), size=size, replace=False)
        spec = self.bank.spec
        sizes = layer_sizes(spec.num_points, spec.ratios)
        records = [self.bank.record(int(j)) for j in picks]
        return bank_batch(records, sizes, rng, self.aug, colour=self.colour)
