"""Helpers for training data: the scan files of a folder, a stable validation split and
class-balanced crop centres (the sources themselves: :mod:`jointseg.training.sources`).

Real labelled rooms are few, so a folder source keeps a named (or deterministic) validation
split out of training, and crops are centred on points drawn with class-balancing weights so
rare classes (board, sofa, column) are seen often enough to be learnt.
"""

from __future__ import annotations

import hashlib
import logging
from pathlib import Path

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.exceptions import ConfigError

log = logging.getLogger(__name__)


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


def centre_weights(labels: np.ndarray, class_weight: np.ndarray) -> np.ndarray:
    """Per-point probability of being a crop centre: proportional to its class's weight
    (unlabelled points get the mean weight), so crops land on rare classes more often."""
    lab = np.asarray(labels)
    w = np.where(lab >= 0, class_weight[np.clip(lab, 0, NUM_CLASSES - 1)], class_weight.mean())
    return w / w.sum()
