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
