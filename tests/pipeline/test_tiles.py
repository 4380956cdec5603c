"""The tile plan for big scans: cores partition the scan, tiles are balanced, margins overlap."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.exceptions import ConfigError
from jointseg.pipeline.tile_params import TileParams
from jointseg.pipeline.tiled.grid import core_tile, plan_tiles


def floor_sample(rng: np.random.Generator, n: int = 200_000) -> np.ndarray:
    """A 60 m x 20 m floor scanned unevenly: a dense corridor along one side, sparse halls."""
    dense = np.column_stack([rng.uniform(0, 60, n // 2), rng.uniform(0, 3, n // 2)])
    sparse = np.column_stack([rng.uniform(0, 60, n // 2), rng.uniform(3, 20, n // 2)])
    return np.vstack([dense, sparse])


def test_a_small_scan_is_one_tile_holding_everything() -> None:
    xy = np.random.default_rng(0).uniform(0, 5, (1000, 2))
    tiles = plan_tiles(xy, 1000, TileParams(max_points=1000))
    assert len(tiles) == 1
    assert tiles[0].core_mask(xy).all() and tiles[0].outer_mask(xy).all()


def test_cores_partition_the_scan_and_hold_similar_counts() -> None:
    rng = np.random.default_rng(1)
    xy = floor_sample(rng)
    total = 20_000_000
    params = TileParams(max_points=4_000_000, overlap=2.0)
    tiles = plan_tiles(xy, total, params)
    assert len(tiles) >= 5
    owner = core_tile(xy, tiles)
    assert (owner >= 0).all()  # every point has exactly one core ...
    hits = sum(t.core_mask(xy).astype(int) for t in tiles)
    assert (hits == 1).all()  # ... and only one
    shares = np.bincount(owner, minlength=len(tiles)) / len(xy)
    # balanced by quantiles although the corridor is eight times denser than the halls
    assert shares.max() * total <= 1.05 * params.max_points
    assert shares.min() > 0.5 * shares.max()


def test_outer_boxes_add_the_margin_inside_the_scan() -> None:
    xy = floor_sample(np.random.default_rng(2))
    tiles = plan_tiles(xy, 12_000_000, TileParams(max_points=4_000_000, overlap=1.5))
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    for tile in tiles:
        core_lo, core_hi = np.array(tile.core_min), np.array(tile.core_max)
        outer_lo, outer_hi = np.array(tile.outer_min), np.array(tile.outer_max)
        np.testing.assert_allclose(outer_lo, np.maximum(core_lo - 1.5, lo))
        np.testing.assert_allclose(outer_hi, np.minimum(core_hi + 1.5, hi))
        assert tile.outer_mask(xy).sum() > tile.core_mask(xy).sum()  # neighbours' points too
    # columns run along the longer side (x here): the first cut is an x cut
    assert tiles[0].core_max[0] < hi[0] and tiles[0].core_min[1] == pytest.approx(lo[1])


def test_bad_samples_are_config_errors() -> None:
    with pytest.raises(ConfigError, match="non-empty"):
        plan_tiles(np.zeros((0, 2)), 10, TileParams())
    with pytest.raises(ConfigError, match=r"\(M, 2\)"):
        plan_tiles(np.zeros((5, 3)), 10, TileParams())
    with pytest.raises(ConfigError, match="non-finite"):
        plan_tiles(np.array([[0.0, np.nan]]), 10, TileParams())
