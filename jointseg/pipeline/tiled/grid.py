"""Cutting a big scan into x-y tiles: the plan only (issue 16's first step).

A scan with more points than ``TileParams.max_points`` is cut into a grid of tiles whose
*cores* partition the scan's x-y extent and whose *outer* boxes add an overlap margin on every
side, wide enough for the network's receptive field and the geometry's neighbourhoods. A point
takes its labels from the tile whose core holds it. Cuts are placed at quantiles of the points'
coordinates (columns along the longer side, then rows inside each column), so tiles hold about
the same number of points even when the density is uneven (a scanned corridor beside an empty
hall).

The plan needs only a sample of the coordinates and the total count, so it can be made from a
stream (the first chunk of a LAS file, or a strided read) without holding the scan.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from jointseg.boxes import in_box
from jointseg.exceptions import ConfigError
from jointseg.pipeline.tile_params import TileParams


@dataclass(frozen=True)
class Tile:
    """One tile: its core (the points it labels) and its outer box (the points it reads).

    Boxes are half-open in x and y, ``[min, max)``, except that the last column and row of the
    scan include their upper edge.
    """

    index: int
    core_min: tuple[float, float]
    core_max: tuple[float, float]
    outer_min: tuple[float, float]
    outer_max: tuple[float, float]

    def core_mask(self, xy: np.ndarray) -> np.ndarray:
        """Points of ``xy`` (N, 2) inside the core (upper edges open)."""
        return in_box(xy, self.core_min, self.core_max, open_upper=True)

    def near_core_mask(self, xy: np.ndarray, margin: float) -> np.ndarray:
        """Points of ``xy`` (N, 2) within ``margin`` of the core (its box grown by it)."""
        lo = np.array(self.core_min) - margin
        hi = np.array(self.core_max) + margin
        return in_box(xy, lo, hi, open_upper=True)

    def outer_mask(self, xy: np.ndarray) -> np.ndarray:
        """Points of ``xy`` (N, 2) inside the outer box (closed: the margin may overlap)."""
        return in_box(xy, self.outer_min, self.outer_max)


def plan_tiles(sample_xy: np.ndarray, total_points: int, params: TileParams) -> list[Tile]:
    """Tiles for a scan of ``total_points`` points of which ``sample_xy`` (M, 2) is a sample.

    Parameters
    ----------
    sample_xy : ndarray of shape (M, 2), metres
        x and y of a uniform sample of the scan's points (all of them for a small scan); its
        extent is taken as the scan's.
    total_points : int
        Points in the whole scan.
    params : TileParams

    Returns
    -------
    list of Tile
        One tile covering everything when ``total_points <= params.max_points``.

    Raises
    ------
    ConfigError
        For an empty sample, a sample that is not (M, 2), or non-finite coordinates.
    """
    xy = np.asarray(sample_xy, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) == 0:
        raise ConfigError(f"sample_xy must be a non-empty (M, 2) array, got shape {xy.shape}")
    if not np.isfinite(xy).all():
        raise ConfigError("sample_xy holds non-finite coordinates")
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    n_tiles = max(1, math.ceil(total_points / params.max_points))
    long_axis = int(np.argmax(hi - lo))
    short_axis = 1 - long_axis
    extent = np.maximum(hi - lo, 1e-9)
    columns, rows = _grid(n_tiles, float(extent[long_axis]), float(extent[short_axis]))
    column_cuts = _cuts(xy[:, long_axis], columns, lo[long_axis], hi[long_axis])
    tiles: list[Tile] = []
    for c in range(columns):
        inside = (xy[:, long_axis] >= column_cuts[c]) & (
            (xy[:, long_axis] < column_cuts[c + 1]) | (c == columns - 1)
        )
        values = xy[inside, short_axis] if inside.any() else xy[:, short_axis]
        row_cuts = _cuts(values, rows, lo[short_axis], hi[short_axis])
        for r in range(rows):
            core_lo = np.empty(2)
            core_hi = np.empty(2)
            core_lo[long_axis], core_hi[long_axis] = column_cuts[c], column_cuts[c + 1]
            core_lo[short_axis], core_hi[short_axis] = row_cuts[r], row_cuts[r + 1]
            tiles.append(_tile(len(tiles), core_lo, core_hi, lo, hi, params.overlap))
    return tiles


def core_tile(xy: np.ndarray, tiles: list[Tile]) -> np.ndarray:
    """The index of the tile whose core holds each point of ``xy`` (N, 2); -1 outside all
    (a point beyond the planned extent, possible when the plan came from a sample)."""
    owner = np.full(len(xy), -1, dtype=np.int64)
    for tile in tiles:
        owner[(owner < 0) & tile.core_mask(xy)] = tile.index
    return owner


def _grid(n_tiles: int, long_extent: float, short_extent: float) -> tuple[int, int]:
    """Columns (across the long side) and rows for at least ``n_tiles`` tiles, with the least
    total length of inner borders: every metre of border is read and segmented twice (the
    overlap), so fewer, squarer cuts cost less; ties go to fewer tiles."""
    best: tuple[float, int, int, int] | None = None
    for columns in range(1, n_tiles + 1):
        rows = math.ceil(n_tiles / columns)
        border = (columns - 1) * short_extent + (rows - 1) * long_extent
        key = (border, columns * rows, columns, rows)
        if best is None or key < best:
            best = key
    assert best is not None
    return best[2], best[3]


def _cuts(values: np.ndarray, parts: int, low: float, high: float) -> np.ndarray:
    """``parts + 1`` cut positions from ``low`` to just above ``high`` at quantiles of
    ``values``, so every part holds about the same share of them."""
    inner = np.quantile(values, np.linspace(0, 1, parts + 1)[1:-1]) if parts > 1 else []
    cuts = np.concatenate([[low], inner, [np.nextafter(high, np.inf)]])
    return np.maximum.accumulate(cuts)


def _tile(
    index: int,
    core_lo: np.ndarray,
    core_hi: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    overlap: float,
) -> Tile:
    """A tile whose outer box is its core grown by ``overlap``, clipped to the scan's extent."""
    outer_lo = np.maximum(core_lo - overlap, lo)
    outer_hi = np.minimum(core_hi + overlap, hi)
    return Tile(
        index,
        (float(core_lo[0]), float(core_lo[1])),
        (float(core_hi[0]), float(core_hi[1])),
        (float(outer_lo[0]), float(outer_lo[1])),
        (float(outer_hi[0]), float(outer_hi[1])),
    )
