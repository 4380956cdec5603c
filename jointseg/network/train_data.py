"""Where training crops come from: synthetic rooms, S3DIS's folder layout, a folder of labelled
scans, or a weighted mix of real scans and synthetic rooms.

Real labelled rooms are few, so a folder source keeps a named (or deterministic) validation
split out of training, and crops are centred on points drawn with class-balancing weights so
rare classes (board, sofa, column) are seen often enough to be learnt.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.network.crops import GridCloud, grid_subsample

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainingSet:
    """Clouds to crop from, how often each is drawn, the validation clouds and a card line."""

    train: list[GridCloud]
    draw_weights: np.ndarray  # (len(train),), sums to 1
    val: list[GridCloud]
    val_names: list[str]
    description: str


def stable_order(names: list[str]) -> list[str]:
    """Names ordered by a hash of the name: a split that does not depend on file order or
    alphabet, and stays the same when rooms are added."""
    return sorted(names, key=lambda n: hashlib.sha1(n.encode()).hexdigest())


def labelled_scan_files(root: Path) -> list[Path]:
    """Every file under ``root`` that :func:`jointseg.io.read_scan` reads, sorted."""
    from jointseg.io.formats import READ_EXTENSIONS

    if not root.is_dir():
        raise ConfigError(f"training data {root}: not a folder, 'synth' or an S3DIS root")
    files = sorted(
        p for p in root.rglob("*") if p.is_file() and p.suffix.lower() in READ_EXTENSIONS
    )
    if not files:
        raise ConfigError(
            f"training data {root}: no scan files ({', '.join(READ_EXTENSIONS)}) and no "
            "Area_N/<room>/Annotations folders"
        )
    return files


def split_validation(names: list[str], val: list[str], val_count: int) -> list[str]:
    """The validation names: those given, else the first ``val_count`` in :func:`stable_order`."""
    if val:
        unknown = sorted(set(val) - set(names))
        if unknown:
            raise ConfigError(f"validation scans not in the training folder: {', '.join(unknown)}")
        return list(val)
    if val_count >= len(names):
        raise ConfigError(
            f"val_count={val_count} leaves no training scan among the {len(names)} in the folder"
        )
    return stable_order(names)[:val_count]


def load_folder(
    root: Path, grid: float, *, val: list[str], val_count: int
) -> tuple[list[GridCloud], list[GridCloud], list[str], list[str]]:
    """Grid-sub-sampled labelled scans of a folder, split into training and validation."""
    from jointseg.io import read_scan

    files = labelled_scan_files(root)
    names = [p.stem for p in files]
    val_names = split_validation(names, val, val_count)
    train: list[GridCloud] = []
    val_clouds: list[GridCloud] = []
    train_names: list[str] = []
    for path in files:
        scan = read_scan(path)
        if scan.labels is None or not (scan.labels >= 0).any():
            raise ConfigError(f"{path}: no 'label' field with class ids, cannot train on it")
        cloud = grid_subsample(scan.xyz, scan.rgb, scan.labels, grid)
        if path.stem in val_names:
            val_clouds.append(cloud)
        else:
            train.append(cloud)
            train_names.append(path.stem)
    return train, val_clouds, train_names, val_names


def centre_weights(labels: np.ndarray, class_weight: np.ndarray) -> np.ndarray:
    """Per-point probability of being a crop centre: proportional to its class's weight
    (unlabelled points get the mean weight), so crops land on rare classes more often."""
    lab = np.asarray(labels)
    w = np.where(lab >= 0, class_weight[np.clip(lab, 0, NUM_CLASSES - 1)], class_weight.mean())
    return w / w.sum()


def mix_weights(n_real: int, n_synth: int, synth_share: float) -> np.ndarray:
    """Draw probabilities: real clouds share ``1 - synth_share``, synthetic ones the rest."""
    if n_synth == 0 or synth_share == 0:
        return np.r_[np.full(n_real, 1.0 / n_real), np.zeros(n_synth)]
    if n_real == 0:
        return np.full(n_synth, 1.0 / n_synth)
    return np.r_[
        np.full(n_real, (1 - synth_share) / n_real), np.full(n_synth, synth_share / n_synth)
    ]
