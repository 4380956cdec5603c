"""Which points lie in an axis-aligned box, one column at a time.

Why: ``np.all((p >= lo) & (p <= hi), axis=1)`` builds two (N, D) boolean arrays and reduces them
along the short axis, which numpy does slowly; four comparisons on the columns, combined in
place, take a tenth of the time (0.2 s against 0.02 s for 4 M points). A tiled run tests every
point against every tile's boxes, so it counted for seconds on a 20 M-point floor.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def in_box(
    points: np.ndarray,
    lo: Sequence[float] | np.ndarray,
    hi: Sequence[float] | np.ndarray,
    *,
    open_upper: bool = False,
) -> np.ndarray:
    """(N,) bool: the rows of ``points`` (N, D) with ``lo <= p <= hi`` on every axis (``p < hi``
    when ``open_upper``)."""
    n, dims = points.shape
    inside = np.ones(n, dtype=bool)
    for axis in range(dims):
        column = points[:, axis]
        inside &= column >= lo[axis]
        inside &= (column < hi[axis]) if open_upper else (column <= hi[axis])
    return inside
