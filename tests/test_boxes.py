"""jointseg.boxes.in_box against the plain numpy expression it replaces, edges included."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.boxes import in_box


@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("open_upper", [False, True])
def test_in_box_is_the_rows_inside_on_every_axis_edges_included(
    dims: int, open_upper: bool
) -> None:
    rng = np.random.default_rng(dims)
    lo = np.full(dims, 2.0)
    hi = np.full(dims, 6.0)
    points = rng.integers(0, 9, (5_000, dims)).astype(np.float64)  # many exactly on an edge
    points[::7] += rng.random((len(points[::7]), dims))
    upper = (points < hi) if open_upper else (points <= hi)
    want = np.all((points >= lo) & upper, axis=1)
    got = in_box(points, lo, hi, open_upper=open_upper)
    assert got.dtype == bool and got.shape == (len(points),)
    np.testing.assert_array_equal(got, want)
    on_upper_edge = np.any(points == hi, axis=1) & np.all((points >= lo) & (points <= hi), axis=1)
    assert on_upper_edge.any()
    assert got[on_upper_edge].all() != open_upper  # the upper edge is in only when closed


def test_in_box_takes_tuples_and_an_empty_set() -> None:
    assert in_box(np.zeros((0, 2)), (0.0, 0.0), (1.0, 1.0)).shape == (0,)
    xy = np.array([[0.5, 0.5], [1.5, 0.5], [0.5, -0.1]])
    np.testing.assert_array_equal(in_box(xy, (0.0, 0.0), (1.0, 1.0)), [True, False, False])
