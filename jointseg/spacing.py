"""Point spacing: the one length scale every adaptive distance threshold is a multiple of."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def estimate_spacing(
    xyz: np.ndarray, *, sample: int = 20_000, rng: np.random.Generator | int | None = 0
) -> float:
    """Median distance from a point to its nearest neighbour, in metres.

    Query points are sampled from whole random cells, so the tree is small even for scans of
    millions of points; the median ignores outliers, and duplicated points' zero distances are
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
    pts = _cell_sample(xyz, sample, gen)
    query = pts[gen.choice(len(pts), size=min(sample, len(pts)), replace=False)]
    # only the distances are read, and the k nearest distances do not depend on the tree's
    # shape: a sliding-midpoint tree, its nodes left as split and on the sample itself (a
    # copy already, or the caller's array, which the tree only reads), builds in half the time
    tree = cKDTree(pts, balanced_tree=False, compact_nodes=False, copy_data=False)
    dist, _ = tree.query(query, k=min(4, len(pts)), workers=-1)
    dist = np.asarray(dist).reshape(len(query), -1)[:, 1:]
    # the nearest non-zero neighbour per query point, so duplicates do not pull the median to 0
    nearest = np.where(dist > 0, dist, np.inf).min(axis=1)
    nearest = nearest[np.isfinite(nearest)]
    return float(np.median(nearest)) if nearest.size else 0.0


def _cell_sample(xyz: np.ndarray, sample: int, rng: np.random.Generator) -> np.ndarray:
    """All points of a random subset of 0.25 m cells, about 20 x ``sample`` points in all.

    A tree over whole cells keeps every sampled point's true neighbours, while building it
    costs a small share of a tree over a scan of millions of points.
    """
    n = len(xyz)
    share = min(1.0, 20 * sample / n)
    if share >= 1.0:
        return xyz
    hashed = np.zeros(n, dtype=np.int64)
    for axis, prime in enumerate((73856093, 19349663, 83492791)):  # a column at a time
        scaled = xyz[:, axis] / 0.25
        key = np.floor(scaled, out=scaled).astype(np.int64)
        key *= prime
        hashed ^= key
    buckets = max(1, int(round(1 / share)))
    hashed %= buckets
    chosen = hashed == rng.integers(buckets)
    return xyz[chosen] if chosen.sum() >= 100 else xyz
