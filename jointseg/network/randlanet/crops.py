"""From a scan to network inputs: grid sub-sampling, crops and the per-layer neighbour indices.

KNN comes from scipy's cKDTree (all cores); a batch of crops is prepared as numpy arrays and
stacked into tensors once.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from jointseg.network.randlanet.config import RandLANetConfig
from jointseg.network.randlanet.crop_arrays import Crop, CropArrays, crop_arrays, search_threads
from jointseg.network.randlanet.crop_arrays import set_search_threads as set_search_threads
from jointseg.voxels import cell_majority, cell_means, voxel_index

MIN_CROP = 1024


@dataclass(frozen=True)
class GridCloud:
    """A grid-sub-sampled scan: the points the network sees, and where each input point went."""

    xyz: np.ndarray  # (M, 3) float32, z relative to the scan's lowest point
    rgb: np.ndarray  # (M, 3) float32 in [0, 1]
    labels: np.ndarray | None  # (M,) int32, majority per cell
    inverse: np.ndarray  # (N,) int64: cell of each input point
    tree: cKDTree
    origin: np.ndarray  # (3,) subtracted from the input coordinates (x, y min and z min)


def grid_subsample(
    xyz: np.ndarray, rgb: np.ndarray | None, labels: np.ndarray | None, grid: float
) -> GridCloud:
    """Average points (and colours) per ``grid``-sized cell; labels by majority vote."""
    inverse, centroids = voxel_index(xyz, grid)
    cells = len(centroids)
    colour = (
        np.zeros((cells, 3))
        if rgb is None
        else cell_means(rgb.astype(np.float64), inverse, cells) / 255.0
    )
    sub_labels = None if labels is None else cell_majority(labels, inverse, cells)
    origin = xyz.min(axis=0)
    pts = (centroids - origin).astype(np.float32)
    return GridCloud(pts, colour.astype(np.float32), sub_labels, inverse, cKDTree(pts), origin)


def crop_indices(cloud: GridCloud, centre: np.ndarray, num_points: int) -> np.ndarray:
    """The ``num_points`` sub-sampled points nearest ``centre`` (all of them if fewer)."""
    n = len(cloud.xyz)
    if n <= num_points:
        return np.arange(n)
    _, idx = cloud.tree.query(centre[None, :], k=num_points, workers=search_threads())
    return np.asarray(idx).reshape(-1)


@dataclass
class Batch:
    """Network inputs for B crops of equal size, and the crops' point indices."""

    features: torch.Tensor
    coords: list[torch.Tensor]
    neighbours: list[torch.Tensor]
    pools: list[torch.Tensor]
    upsamples: list[torch.Tensor]
    indices: np.ndarray  # (B, N) indices into the GridCloud
    labels: torch.Tensor | None

    @classmethod
    def from_arrays(cls, arrays: CropArrays) -> Batch:
        """The numpy inputs (:func:`crop_arrays`) as tensors sharing their memory."""
        tensors = [
            [torch.from_numpy(a) for a in layers]
            for layers in (arrays.coords, arrays.neighbours, arrays.pools, arrays.upsamples)
        ]
        return cls(
            torch.from_numpy(arrays.features),
            tensors[0],
            tensors[1],
            tensors[2],
            tensors[3],
            arrays.indices,
            None if arrays.labels is None else torch.from_numpy(arrays.labels),
        )

    def to(self, device: torch.device | str, *, non_blocking: bool = False) -> Batch:
        """Move every tensor to ``device`` (without waiting, from pinned memory, when
        ``non_blocking``)."""
        return self._map(lambda t: t.to(device, non_blocking=non_blocking))

    def pin_memory(self) -> Batch:
        """Every tensor in page-locked memory, for fast asynchronous copies to a GPU (what a
        DataLoader with ``pin_memory`` calls)."""
        return self._map(lambda t: t.pin_memory())

    def _map(self, move: Callable[[torch.Tensor], torch.Tensor]) -> Batch:
        return Batch(
            move(self.features),
            [move(t) for t in self.coords],
            [move(t) for t in self.neighbours],
            [move(t) for t in self.pools],
            [move(t) for t in self.upsamples],
            self.indices,
            None if self.labels is None else move(self.labels),
        )


def pad_to(indices: np.ndarray, size: int, rng: np.random.Generator) -> np.ndarray:
    """Repeat random points of a small crop until it has ``size`` points."""
    if len(indices) >= size:
        return indices
    extra = rng.choice(indices, size=size - len(indices), replace=True)
    return np.concatenate([indices, extra])


def build_batch(
    crops: Sequence[Crop],
    config: RandLANetConfig,
) -> Batch:
    """Per-layer neighbours, pooling and upsampling indices for crops of equal size
    (:func:`~jointseg.network.randlanet.crop_arrays.crop_arrays`), as tensors.

    Each crop is (xyz (N, 3) float32, rgb (N, 3) float32, labels (N,) or None, indices (N,)),
    already shuffled: the first N / ratio points of a layer are its random sample.
    """
    return Batch.from_arrays(crop_arrays(crops, config))
