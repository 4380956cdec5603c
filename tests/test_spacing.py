"""Point spacing on grids whose spacing is known by construction."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.spacing import estimate_spacing


@pytest.mark.parametrize("step", [0.01, 0.05])
def test_spacing_of_a_regular_grid_is_its_step(step: float) -> None:
    g = np.arange(60) * step
    xx, yy = np.meshgrid(g, g)
    xyz = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    assert estimate_spacing(xyz) == pytest.approx(step, rel=1e-6)


def test_spacing_ignores_duplicated_points() -> None:
    g = np.arange(50) * 0.02
    xx, yy = np.meshgrid(g, g)
    xyz = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    doubled = np.vstack([xyz, xyz])
    assert estimate_spacing(doubled) == pytest.approx(0.02, rel=1e-6)


def test_spacing_of_tiny_scans_is_zero() -> None:
    assert estimate_spacing(np.zeros((1, 3))) == 0.0
    assert estimate_spacing(np.zeros((5, 3))) == 0.0


def _reference_spacing(xyz: np.ndarray, *, sample: int, rng: int) -> float:
    """estimate_spacing as first written (a balanced tree, the hash of whole cells)."""
    from scipy.spatial import cKDTree

    n = len(xyz)
    gen = np.random.default_rng(rng)
    share = min(1.0, 20 * sample / n)
    pts = xyz
    if share < 1.0:
        keys = np.floor(xyz / 0.25).astype(np.int64)
        hashed = (keys[:, 0] * 73856093) ^ (keys[:, 1] * 19349663) ^ (keys[:, 2] * 83492791)
        buckets = max(1, int(round(1 / share)))
        chosen = hashed % buckets == gen.integers(buckets)
        pts = xyz[chosen] if chosen.sum() >= 100 else xyz
    query = pts[gen.choice(len(pts), size=min(sample, len(pts)), replace=False)]
    dist, _ = cKDTree(pts).query(query, k=min(4, len(pts)), workers=-1)
    dist = np.asarray(dist).reshape(len(query), -1)[:, 1:]
    nearest = np.where(dist > 0, dist, np.inf).min(axis=1)
    nearest = nearest[np.isfinite(nearest)]
    return float(np.median(nearest)) if nearest.size else 0.0


@pytest.mark.parametrize(("n", "sample"), [(3000, 20_000), (60_000, 300), (40_000, 50)])
def test_spacing_matches_the_balanced_tree_to_the_bit(n: int, sample: int) -> None:
    rng = np.random.default_rng(n)
    xyz = rng.uniform(-3.0, 3.0, (n, 3)) * [1.0, 1.0, 0.3]
    xyz[: n // 10] = xyz[n // 10 : 2 * (n // 10)]  # duplicates: zero distances to skip
    for seed in (0, 5):
        assert estimate_spacing(xyz, sample=sample, rng=seed) == _reference_spacing(
            xyz, sample=sample, rng=seed
        )
