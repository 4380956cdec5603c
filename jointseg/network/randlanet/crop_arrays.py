"""A batch of crops as the network's input arrays, in numpy alone: the per-layer neighbour,
pooling and up-sampling indices from scipy's cKDTree.

Why apart from :mod:`jointseg.network.randlanet.crops`: the compiled forward pass
(:mod:`jointseg.network.randlanet.compiled`) feeds these arrays to OpenVINO without importing
torch, which costs a command-line run about a second of one core.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from jointseg.network.randlanet.config import RandLANetConfig

#: Threads of each KD-tree search (-1: all cores). Batch-building worker processes set 1: the
#: processes are the parallelism there, and threads of each would only contend.
_search_threads = -1


def set_search_threads(threads: int) -> None:
    """Threads per KD-tree search in this process (-1 for all cores)."""
    global _search_threads
    _search_threads = threads


def search_threads() -> int:
    """Threads per KD-tree search in this process (:func:`set_search_threads`)."""
    return _search_threads


Crop = tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]


@dataclass(frozen=True)
class CropArrays:
    """Network inputs for B crops of equal size as numpy arrays, and the crops' point indices.

    ``coords``, ``neighbours``, ``pools`` and ``upsamples`` hold one (B, ...) array per layer.
    """

    features: np.ndarray  # (B, N, 6) float32
    coords: list[np.ndarray]
    neighbours: list[np.ndarray]
    pools: list[np.ndarray]
    upsamples: list[np.ndarray]
    indices: np.ndarray  # (B, N) indices into the sub-sampled cloud
    labels: np.ndarray | None  # (B, N) int64, when every crop has labels

    def flat(self) -> list[np.ndarray]:
        """The inputs in the exported model's order: features, then each list layer by layer."""
        return [self.features, *self.coords, *self.neighbours, *self.pools, *self.upsamples]


def crop_arrays(crops: Sequence[Crop], config: RandLANetConfig) -> CropArrays:
    """Per-layer neighbours, pooling and upsampling indices for crops of equal size.

    Each crop is (xyz (N, 3) float32, rgb (N, 3) float32, labels (N,) or None, indices (N,)),
    already shuffled: the first N / ratio points of a layer are its random sample.
    """
    feats, labels, idx = [], [], []
    per_layer: list[list[list[np.ndarray]]] = [[], [], [], []]
    for xyz, rgb, lab, ind in crops:
        pts = xyz.copy()
        pts[:, :2] -= pts[:, :2].mean(axis=0)
        feats.append(np.concatenate([pts, rgb], axis=1))
        labels.append(lab)
        idx.append(ind)
        layers = layer_indices(pts, config)
        for slot, arrays in zip(per_layer, layers, strict=True):
            slot.append(arrays)
    stacked = [
        [np.stack([crop[i] for crop in slot]) for i in range(len(slot[0]))] for slot in per_layer
    ]
    known = [lab for lab in labels if lab is not None]
    label_array = np.stack(known).astype(np.int64) if len(known) == len(labels) else None
    return CropArrays(
        np.stack(feats), stacked[0], stacked[1], stacked[2], stacked[3], np.stack(idx), label_array
    )


def layer_indices(
    pts: np.ndarray, config: RandLANetConfig
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """One crop's coordinates, neighbours, pooling and up-sampling indices for every layer."""
    coords, neighbours, pools, ups = [], [], [], []
    current = pts
    for ratio in config.ratios:
        tree = cKDTree(current)
        k = min(config.k, len(current))
        _, nb = tree.query(current, k=k, workers=_search_threads)
        nb = np.asarray(nb).reshape(len(current), k)
        if k < config.k:
            nb = np.concatenate([nb, np.repeat(nb[:, :1], config.k - k, axis=1)], axis=1)
        keep = max(1, len(current) // ratio)
        sub = current[:keep]
        _, up = cKDTree(sub).query(current, k=1, workers=_search_threads)
        coords.append(current)
        neighbours.append(nb.astype(np.int64))
        pools.append(nb[:keep].astype(np.int64))
        ups.append(np.asarray(up).reshape(-1, 1).astype(np.int64))
        current = sub
    return coords, neighbours, pools, ups
