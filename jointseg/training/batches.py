"""Training batches: augmented crops drawn from the sources, built by worker processes.

Batch ``i`` of a run is drawn from its own generator, seeded with ``(seed, i)``: the batches are
the same whether one process builds them or N workers do, in any order, and a resumed run
continues with the batches it would have drawn. Workers are torch DataLoader processes (fork),
each on one thread; batches come back through shared memory and, for a GPU, are pinned and
copied without blocking. With ``neighbours_on_device`` the workers send crops only and the
per-layer neighbour searches run on the GPU (:mod:`jointseg.network.randlanet.knn`).
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Iterator
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass

import numpy as np
import torch

from jointseg.network.batches import Prefetcher
from jointseg.network.randlanet.crops import (
    MIN_CROP,
    Batch,
    GridCloud,
    build_batch,
    pad_to,
    set_search_threads,
)
from jointseg.network.randlanet.model import RandLANetConfig
from jointseg.training.augment import (
    AugmentParams,
    add_stray_points,
    augment,
    cut_region,
    density_sample,
    sensor_gaps,
)

#: A crop's region reaches this much beyond the radius its points would span at the network's
#: grid, so sparser sampling and cut regions still fill a crop.
REGION_MARGIN = 1.6

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Crop:
    """One training crop: points, colours in [0, 1], labels (-1 unknown)."""

    xyz: np.ndarray
    rgb: np.ndarray
    labels: np.ndarray


@dataclass
class CropBatch:
    """Crops of equal size stacked, before the neighbour searches (built on the device)."""

    xyz: torch.Tensor  # (B, N, 3) float32
    rgb: torch.Tensor  # (B, N, 3) float32
    labels: torch.Tensor  # (B, N) int64

    def pin_memory(self) -> CropBatch:
        return CropBatch(self.xyz.pin_memory(), self.rgb.pin_memory(), self.labels.pin_memory())


def region_crop(
    cloud: GridCloud,
    centre: np.ndarray,
    num_points: int,
    grid: float,
    rng: np.random.Generator,
    aug: AugmentParams,
) -> Crop:
    """The crop around ``centre`` as a user's scan would give it: the region cut (partial room,
    slice) and sub-sampled at a random density, then at the network's grid, then the
    ``num_points`` nearest the centre."""
    spacing = grid
    if rng.random() < aug.density:
        spacing = float(rng.uniform(*aug.density_range))
    # the region holding num_points cells of side max(spacing, grid), with a margin
    cells = np.pi * (np.sqrt(num_points / np.pi) * max(spacing, grid)) ** 2
    radius = REGION_MARGIN * float(np.sqrt(cells / np.pi))
    idx = np.asarray(cloud.tree.query_ball_point(centre, radius, workers=1))
    if len(idx) < MIN_CROP:
        _, near = cloud.tree.query(centre[None, :], k=min(len(cloud.xyz), num_points * 4))
        idx = np.asarray(near).reshape(-1)
    xyz, rgb = cloud.xyz[idx], cloud.rgb[idx]
    assert cloud.labels is not None
    lab = cloud.labels[idx]
    keep = cut_region(xyz, centre, rng, aug)
    if keep is not None and keep.sum() >= MIN_CROP:
        xyz, rgb, lab = xyz[keep], rgb[keep], lab[keep]
    keep = sensor_gaps(xyz, lab, centre, rng, aug)
    if keep is not None and keep.sum() >= MIN_CROP:
        xyz, rgb, lab = xyz[keep], rgb[keep], lab[keep]
    if spacing < grid:
        xyz, rgb, lab = density_sample(xyz, rgb, lab, spacing, rng)
    xyz, rgb, lab = density_sample(xyz, rgb, lab, max(spacing, grid), rng)
    d2 = ((xyz - centre) ** 2).sum(axis=1)
    if len(d2) > num_points:
        near = np.argpartition(d2, num_points - 1)[:num_points]
        xyz, rgb, lab = xyz[near], rgb[near], lab[near]
    return Crop(xyz, rgb, lab)


def training_crop(
    cloud: GridCloud,
    num_points: int,
    grid: float,
    rng: np.random.Generator,
    aug: AugmentParams,
    centre_p: np.ndarray | None = None,
) -> Crop:
    """An augmented, shuffled training crop around a random point (drawn with ``centre_p``);
    up to a tenth of its points dropped, then padded back to at least ``MIN_CROP``."""
    n = len(cloud.xyz)
    centre = cloud.xyz[rng.choice(n, p=centre_p) if centre_p is not None else rng.integers(n)]
    crop = region_crop(cloud, centre, num_points, grid, rng, aug)
    order = np.arange(len(crop.xyz))
    if len(order) > MIN_CROP:
        order = order[rng.random(len(order)) >= rng.uniform(0, 0.1)]
    order = rng.permutation(pad_to(order, min(num_points, max(len(order), MIN_CROP)), rng))
    xyz, rgb = augment(crop.xyz[order], crop.rgb[order], rng, aug)
    xyz, rgb, labels = add_stray_points(xyz, rgb, crop.labels[order].astype(np.int64), rng, aug)
    return Crop(xyz, rgb, labels)


@dataclass
class BatchMaker:
    """Batch ``i`` of a run, from anywhere: what a worker process needs and nothing more."""

    clouds: list[GridCloud]
    draw_p: np.ndarray
    centre_p: list[np.ndarray | None]
    model_config: RandLANetConfig
    aug: AugmentParams
    batch_size: int
    num_points: int
    seed: int
    first: int = 0  # the global index of item 0 (resumed runs)
    count: int = 0
    neighbours_on_device: bool = False

    def __len__(self) -> int:
        return self.count

    def crops(self, i: int) -> list[Crop]:
        """The crops of global batch ``i``, cut to a common size."""
        rng = np.random.default_rng([self.seed, i])
        picks = rng.choice(len(self.clouds), size=self.batch_size, p=self.draw_p)
        crops = [
            training_crop(
                self.clouds[k],
                self.num_points,
                self.model_config.grid_size,
                rng,
                self.aug,
                self.centre_p[k],
            )
            for k in picks
        ]
        size = min(len(c.xyz) for c in crops)
        return [Crop(c.xyz[:size], c.rgb[:size], c.labels[:size]) for c in crops]

    def __getitem__(self, item: int) -> Batch | CropBatch:
        crops = self.crops(self.first + item)
        if self.neighbours_on_device:
            return CropBatch(
                torch.from_numpy(np.stack([c.xyz for c in crops])),
                torch.from_numpy(np.stack([c.rgb for c in crops])),
                torch.from_numpy(np.stack([c.labels for c in crops])),
            )
        return build_batch(
            [(c.xyz, c.rgb, c.labels, np.arange(len(c.xyz))) for c in crops], self.model_config
        )


def _one_thread(_: int) -> None:
    torch.set_num_threads(1)
    set_search_threads(1)


def batch_stream(
    maker: BatchMaker, *, workers: int, prefetch: bool, pin: bool
) -> AbstractContextManager[Iterator[Batch | CropBatch]]:
    """The maker's batches in order: built by ``workers`` processes, or in this process (a step
    ahead in a thread when ``prefetch``)."""
    if workers > 0 and "openvino" in sys.modules:
        # OpenVINO's thread pools do not survive a fork (a forked worker segfaulted in CI)
        log.warning("OpenVINO is loaded in this process: batches built here, not in workers")
        workers = 0
    if workers > 0:
        # Batches hold 21 tensors; passing each as a named shared-memory file instead of a
        # file descriptor halves the training process's cost of receiving them (measured on
        # 2 cores: 7.8 -> 3.5 ms a batch, and 2 workers 1.63x -> 1.79x one worker).
        torch.multiprocessing.set_sharing_strategy("file_system")
        loader: torch.utils.data.DataLoader = torch.utils.data.DataLoader(
            maker,  # type: ignore[arg-type]
            batch_size=None,
            shuffle=False,
            num_workers=workers,
            pin_memory=pin,
            prefetch_factor=4,
            worker_init_fn=_one_thread,
            multiprocessing_context="fork",
        )
        return _Closing(iter(loader))
    items = (maker[i] for i in range(len(maker)))
    return Prefetcher(items) if prefetch else nullcontext(items)


class _Closing(AbstractContextManager):
    """A DataLoader iterator whose worker processes stop when the block ends."""

    def __init__(self, iterator: Iterator) -> None:
        self.iterator = iterator

    def __enter__(self) -> Iterator:
        return self.iterator

    def __exit__(self, *exc: object) -> None:
        shutdown = getattr(self.iterator, "_shutdown_workers", None)
        if shutdown is not None:
            shutdown()
