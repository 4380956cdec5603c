"""Real rooms laid side by side in x: a scan of a given size made of real S3DIS points, for the
speed benchmarks (the rooms in ../shared are small and sparse, so nearly every point survives a
network's 4 cm grid and the work per point is that of a dense real scan of the same size)."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from helpers.inputs import AREA6
from jointseg.scan import Scan


def rooms_side_by_side(points: int, folder: Path = AREA6, gap: float = 1.0) -> Scan | None:
    """Whole rooms of ``folder`` (sorted by name, again from the first when all are used) side by
    side in x with ``gap`` metres between them, until at least ``points`` points; None when the
    folder holds no rooms."""
    from jointseg.io import read_scan

    paths = sorted(folder.glob("*.ply")) if folder.is_dir() else []
    if not paths:
        return None
    xyz: list[np.ndarray] = []
    rgb: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    total, x0 = 0, 0.0
    for path in itertools.cycle(paths):
        room = read_scan(path)
        shifted = room.xyz - room.xyz.min(axis=0) + np.array([x0, 0.0, 0.0])
        x0 = float(shifted[:, 0].max()) + gap
        xyz.append(shifted)
        rgb.append(room.rgb if room.rgb is not None else np.zeros((len(room), 3), np.uint8))
        labels.append(room.labels if room.labels is not None else np.full(len(room), -1))
        total += len(room)
        if total >= points:
            break
    return Scan(np.concatenate(xyz), np.concatenate(rgb), np.concatenate(labels))
