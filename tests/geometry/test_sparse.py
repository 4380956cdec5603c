"""Sparse scans (a room thinned to one point per 3.3 cm, a far-range scan): the voxel size and
the plane tolerance stop growing with the spacing at SPARSE_SPACING, so what stands a few
centimetres off a wall is not swallowed by the wall's plane."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.geometry import GeometryParams, segment
from jointseg.geometry.params import SPARSE_SPACING, resolve
from jointseg.scan import Scan
from jointseg.spacing import estimate_spacing

#: A grid of this pitch (m), jittered: sparser than SPARSE_SPACING, as a room thinned to one
#: point per 3.3 cm cell (2.3 to 2.5 cm between neighbours).
STEP = 0.03
#: How far the panel stands off its wall (m): under the uncapped tolerance on such a scan
#: (2.5 x its spacing), over the capped one (2.5 x SPARSE_SPACING).
PROUD = 0.06


def _rect(rng: np.random.Generator, lo: tuple, hi: tuple) -> np.ndarray:
    """A jittered STEP grid on an axis-aligned rectangle (one axis constant)."""
    axes = [np.arange(low, h + 1e-9, STEP) if h > low else np.array([low])
            for low, h in zip(lo, hi, strict=True)]  # fmt: skip
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return grid + rng.normal(0, 0.002, grid.shape)


def _sparse_room() -> tuple[Scan, np.ndarray, np.ndarray]:
    """A 5 x 4 x 2.6 m box room at about STEP spacing with a 1.2 x 0.9 m panel (a board, a
    cabinet's back) standing PROUD off the x = 0 wall; the wall's and the panel's points."""
    rng = np.random.default_rng(5)
    parts = [
        _rect(rng, (0, 0, 0), (5, 4, 0)),
        _rect(rng, (0, 0, 2.6), (5, 4, 2.6)),
        _rect(rng, (0, 0, 0), (0, 4, 2.6)),
        _rect(rng, (5, 0, 0), (5, 4, 2.6)),
        _rect(rng, (0, 0, 0), (5, 0, 2.6)),
        _rect(rng, (0, 4, 0), (5, 4, 2.6)),
        _rect(rng, (PROUD, 1.0, 0.8), (PROUD, 2.2, 1.7)),
    ]
    xyz = np.vstack(parts)
    which = np.concatenate([np.full(len(p), i) for i, p in enumerate(parts)])
    rgb = np.where((which == 6)[:, None], [40, 60, 160], [200, 200, 195]).astype(np.uint8)
    return Scan(xyz=xyz.astype(np.float32), rgb=rgb), which == 2, which == 6


def _swallowed(params: GeometryParams, scan: Scan, wall: np.ndarray, panel: np.ndarray) -> float:
    """Share of the panel's points in the wall's main plane."""
    plane_id = segment(scan, params, seed=0).plane_id
    wall_plane = np.bincount(plane_id[wall][plane_id[wall] >= 0]).argmax()
    return float(np.mean(plane_id[panel] == wall_plane))


def test_the_voxel_and_plane_tolerance_stop_growing_with_the_spacing() -> None:
    def plane(spacing: float) -> float:
        return resolve(GeometryParams(), n_points=100_000, spacing=spacing, colour_noise=None,
                       yaw_deg=0.0).plane_distance  # fmt: skip

    assert plane(0.01) == pytest.approx(0.025)
    assert plane(0.03) == pytest.approx(2.5 * SPARSE_SPACING)
    # the cluster tolerance still follows the spacing: sparse points must stay connected
    assert resolve(GeometryParams(), n_points=100_000, spacing=0.03, colour_noise=None,
                   yaw_deg=0.0).cluster_distance == pytest.approx(0.09)  # fmt: skip


def test_a_panel_off_a_sparse_wall_is_not_swallowed_by_its_plane() -> None:
    scan, wall, panel = _sparse_room()
    spacing = estimate_spacing(scan.xyz)
    assert 2.5 * SPARSE_SPACING < PROUD < 2.5 * spacing
    assert _swallowed(GeometryParams(), scan, wall, panel) < 0.1
    # the same scan with the tolerances grown with its spacing, as before the cap
    grown = GeometryParams(voxel_factor=2.5 * spacing / SPARSE_SPACING,
                           plane_distance=2.5 * spacing)  # fmt: skip
    assert _swallowed(grown, scan, wall, panel) > 0.5
