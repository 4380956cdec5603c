"""Point spacing: the one length scale every adaptive distance threshold is a multiple of."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def estimate_spacing(
    xyz: np.ndarray, *, sample: int = 20_000, rng: np.random.Generator | int | None = 0
) -> float:
    """Median distance from a point to its nearest neighbour, in metres.

    A random sample of query points against a tree on all points keeps this O(N log N) in the
    tree build only; the median ignores outliers and duplicated points' zero distances are
    skipped so merged scans with repeated points still give a useful scale.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), metres
    sample : int
        Number of query points.
    rng : Generator or int or None
        Randomness for the sample, deterministic by default.

    Returns
    -------
    float
        0.0 when the scan has fewer than two distinct points.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    n = xyz.shape[0]
    if n < 2:
        return 0.0
    gen = np.random.default_rng(rng)
    idx = gen.choice(n, size=min(sample, n), replace=False) if n > sample else np.arange(n)
    tree = cKDTree(xyz)
    dist, _ = tree.query(xyz[idx], k=min(4, n), workers=-1)
    dist = np.asarray(dist)[:, 1:]
    positive = dist[dist > 0]
    if positive.size == 0:
        return 0.0
    # the nearest non-zero neighbour per query point, so duplicates do not pull the median to 0
    nearest = np.where(dist > 0, dist, np.inf).min(axis=1)
    nearest = nearest[np.isfinite(nearest)]
    return float(np.median(nearest))
