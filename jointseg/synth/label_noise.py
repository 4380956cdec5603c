"""A stand-in for a network's mistakes: ground truth with spatially coherent label noise.

A segmentation network errs in patches (a chair's legs called table, the lower part of a wall
called clutter), not point by point. Fusion is tested and benchmarked without trained weights
by corrupting the synthetic ground truth in such patches plus a little salt noise.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from jointseg.classes import NUM_CLASSES
from jointseg.exceptions import ConfigError


def corrupt_labels(
    xyz: np.ndarray,
    labels: np.ndarray,
    *,
    rng: np.random.Generator,
    patches: int = 40,
    radius: float = 0.3,
    salt: float = 0.05,
) -> tuple[np.ndarray, np.ndarray]:
    """Wrong labels in ball-shaped patches and at random points; soft scores to match.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), metres
    labels : ndarray of shape (N,), int
        Ground truth, 0..12 (-1 points take a random class).
    rng : numpy.random.Generator
    patches : int
        Number of patches, centred on random points; each gets one class drawn from those
        present in the scan.
    radius : float
        Patch radius in metres.
    salt : float
        Share of points given a uniformly random class.

    Returns
    -------
    labels : ndarray of shape (N,), int32
        The corrupted labels.
    probs : ndarray of shape (N, 13), float32
        Scores whose argmax is the corrupted label: 0.6-0.95 where the label is right; where it
        is wrong 0.3-0.9 in patches (networks are often confidently wrong over a whole patch)
        and 0.3-0.5 at salt points, with the true class second.
    """
    labels = np.asarray(labels)
    n = len(labels)
    if xyz.shape != (n, 3):
        raise ConfigError(f"xyz must have shape ({n}, 3), got {xyz.shape}")
    if n == 0:
        return np.zeros(0, np.int32), np.zeros((0, NUM_CLASSES), np.float32)
    present = np.unique(labels[labels >= 0])
    if len(present) == 0:
        present = np.arange(NUM_CLASSES)
    out = np.where(labels >= 0, labels, rng.integers(0, NUM_CLASSES, n)).astype(np.int32)
    if patches > 0:
        centres = xyz[rng.choice(n, size=min(patches, n), replace=False)]
        dist, nearest = cKDTree(centres).query(xyz, workers=-1)
        patch_label = rng.choice(present, size=len(centres))
        inside = dist < radius
        out[inside] = patch_label[nearest[inside]]
    else:
        inside = np.zeros(n, dtype=bool)
    flip = rng.random(n) < salt
    out[flip] = rng.integers(0, NUM_CLASSES, int(flip.sum()))

    wrong = out != labels
    probs = rng.uniform(0.0, 0.05, (n, NUM_CLASSES)).astype(np.float32)
    rows = np.arange(n)
    wrong_score = np.where(inside & ~flip, rng.uniform(0.3, 0.9, n), rng.uniform(0.3, 0.5, n))
    probs[rows, out] = np.where(wrong, wrong_score, rng.uniform(0.6, 0.95, n))
    truth = wrong & (labels >= 0)
    probs[rows[truth], labels[truth]] = 0.6 * probs[rows[truth], out[truth]]
    probs /= probs.sum(axis=1, keepdims=True)
    return out, probs
