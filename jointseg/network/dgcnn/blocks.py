"""The S3DIS block convention of PointNet / DGCNN: vertical 1 m x 1 m columns on a regular grid,
a fixed number of points sampled per column, 9 features per point.

The reference (PointNet's ``indoor3d_util.room2blocks``) sweeps columns with corners at
``(i * stride, j * stride)`` over the room shifted to start at the origin, keeps a point in every
column whose closed square contains it, drops columns with fewer than 100 points and samples
4 096 points per column (repeating random points of a smaller column). Here every column is
covered by as many disjoint random samples as ``coverage`` asks for, so whole scans get a
prediction per point, and all of it is index arithmetic on arrays, no loop over columns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

#: Tolerance (metres) on the column borders, so a point on a border lands in both columns.
EDGE_EPS = 1e-9


@dataclass(frozen=True)
class Columns:
    """Grid columns and the points inside each.

    Attributes
    ----------
    points : ndarray of shape (P,), int64
        Point indices grouped by column (a point appears once per column containing it).
    start : ndarray of shape (C + 1,), int64
        Column c holds ``points[start[c]:start[c + 1]]``.
    weight : ndarray of shape (P,), float64
        1 / (number of kept columns containing the point): summed per column, how many
        points the column owns when every point is shared evenly.
    """

    points: np.ndarray
    start: np.ndarray
    weight: np.ndarray

    @property
    def sizes(self) -> np.ndarray:
        """Points per column, (C,) int64."""
        return np.diff(self.start)

    def __len__(self) -> int:
        return len(self.start) - 1


def _cells_1d(coord: np.ndarray, count: int, size: float, stride: float) -> tuple[np.ndarray, ...]:
    """Every (point, cell) pair along one axis: cell i spans [i * stride, i * stride + size]."""
    lo = np.ceil((coord - size - EDGE_EPS) / stride).astype(np.int64)
    hi = np.floor((coord + EDGE_EPS) / stride).astype(np.int64)
    lo, hi = np.clip(lo, 0, count - 1), np.clip(hi, 0, count - 1)
    n = hi - lo + 1
    point = np.repeat(np.arange(len(coord)), n)
    offset = np.arange(len(point)) - np.repeat(np.cumsum(n) - n, n)
    return point, lo[point] + offset


def column_blocks(
    xy: np.ndarray, *, size: float = 1.0, stride: float = 1.0, min_points: int = 100
) -> Columns:
    """Partition points into overlapping vertical columns, as the reference does.

    Parameters
    ----------
    xy : ndarray of shape (N, 2), metres
        Horizontal coordinates, shifted so the minimum is 0 (the reference's room origin).
    size : float, metres
        Column width (1 m in the published weights' training data).
    stride : float, metres
        Distance between column corners; ``stride < size`` makes columns overlap.
    min_points : int
        Columns with fewer points are dropped (100 in the reference), unless every column is
        that small (a tiny scan keeps all of them). A point left in no column gets a prediction
        from its nearest predicted neighbour.

    Returns
    -------
    Columns
    """
    if len(xy) == 0:
        return Columns(np.zeros(0, np.int64), np.zeros(1, np.int64), np.zeros(0))
    limit = xy.max(axis=0)
    counts = [max(1, int(np.ceil((float(lim) - size) / stride)) + 1) for lim in limit]
    px, cx = _cells_1d(xy[:, 0], counts[0], size, stride)
    py, cy = _cells_1d(xy[:, 1], counts[1], size, stride)
    # combine: each point's x-cells times its y-cells
    nx = np.bincount(px, minlength=len(xy))
    ny = np.bincount(py, minlength=len(xy))
    per_point = nx * ny
    point = np.repeat(np.arange(len(xy)), per_point)
    rank = np.arange(len(point)) - np.repeat(np.cumsum(per_point) - per_point, per_point)
    x_start = np.cumsum(nx) - nx
    y_start = np.cumsum(ny) - ny
    col = cx[x_start[point] + rank // ny[point]] * counts[1] + cy[y_start[point] + rank % ny[point]]
    sizes = np.bincount(col, minlength=counts[0] * counts[1])
    keep = sizes >= min_points
    if not keep.any():
        keep = sizes > 0
    mask = keep[col]
    point, col = point[mask], col[mask]
    order = np.argsort(col, kind="stable")
    point, col = point[order], col[order]
    kept_sizes = np.bincount(col, minlength=len(sizes))[keep]
    start = np.concatenate([[0], np.cumsum(kept_sizes)])
    shares = np.bincount(point, minlength=len(xy))
    return Columns(point, start, 1.0 / shares[point])


def sample_columns(
    columns: Columns, num_points: int, *, coverage: float | None, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Disjoint random samples of ``num_points`` points from every column.

    A column of P points gets ``round(coverage * owned / num_points)`` samples (at least one,
    at most enough for all P), where ``owned`` is its share of points (a point in four
    overlapping columns counts a quarter in each): ``coverage`` is then roughly how many
    predictions each point receives, whatever the overlap, and the cost grows with the
    points, not with the overlap (a column smaller than a sample still costs one). ``None``
    covers every point of every column (``ceil(P / num_points)`` samples). Samples are
    consecutive slices of a random permutation of the column; the last one is topped up with
    the column's first points, and a column smaller than ``num_points`` repeats random points
    of its own, as the reference does.

    Returns
    -------
    samples : ndarray of shape (S, num_points), int64
        Point indices of every sample.
    column : ndarray of shape (S,), int64
        The column each sample was drawn from.
    """
    sizes = columns.sizes
    if len(sizes) == 0:
        return np.zeros((0, num_points), np.int64), np.zeros(0, np.int64)
    col_of = np.repeat(np.arange(len(sizes)), sizes)
    # shuffle within each column: sort by (column, random key)
    perm = np.lexsort((rng.random(len(col_of)), col_of))
    shuffled = columns.points[perm]
    full = np.ceil(sizes / num_points).astype(np.int64)
    if coverage is None:
        per_column = full
    else:
        owned = np.bincount(col_of, weights=columns.weight, minlength=len(sizes))
        per_column = np.floor(coverage * owned / num_points + 0.5).astype(np.int64)
        per_column = np.clip(per_column, 1, full)
    column = np.repeat(np.arange(len(sizes)), per_column)
    first = np.repeat(np.cumsum(per_column) - per_column, per_column)
    local = (np.arange(len(column)) - first)[:, None] * num_points + np.arange(num_points)
    size = sizes[column][:, None]
    wrapped = np.where(size >= num_points, local % size, rng.integers(0, size, local.shape))
    local = np.where(local < size, local, wrapped)
    return shuffled[columns.start[column][:, None] + local], column


def block_features(
    xyz: np.ndarray,
    rgb: np.ndarray,
    extent: np.ndarray,
    *,
    size: float = 1.0,
    shift: np.ndarray | None = None,
) -> np.ndarray:
    """The reference's 9 input features of sampled blocks.

    Parameters
    ----------
    xyz : ndarray of shape (B, M, 3), metres
        Sampled points in the room frame (floor or scan minimum at z = 0, x, y from 0).
    rgb : ndarray of shape (B, M, 3)
        Colour in 0-1.
    extent : ndarray of shape (3,) or (B, 1, 3), metres
        The room size the normalised coordinates divide by.
    size : float, metres
        Block width; x and y are centred at the sample's minimum plus half of it.
    shift : ndarray of shape (B, 1, 3), optional, metres
        Subtracted before normalising: where each block's room starts, when it is not the
        frame's origin.

    Returns
    -------
    ndarray of shape (B, M, 9), float32
        ``[x - (min x + size / 2), y - (min y + size / 2), z, r, g, b, x / X, y / Y, z / Z]``.
    """
    centred = xyz.copy()
    centred[..., :2] -= xyz[..., :2].min(axis=1, keepdims=True) + size / 2
    normalised = (xyz if shift is None else xyz - shift) / extent
    return np.concatenate([centred, rgb, normalised], axis=-1).astype(np.float32)


def fill_unseen(probs: np.ndarray, seen: np.ndarray, xyz: np.ndarray) -> None:
    """Give the points no sample held (``~seen``) their nearest covered point's probabilities,
    in place: columns below ``min_points`` are dropped, so a few points are never predicted."""
    if seen.all():
        return
    covered = np.flatnonzero(seen)
    missing = np.flatnonzero(~seen)
    _, nearest = cKDTree(xyz[covered]).query(xyz[missing], k=1, workers=-1)
    probs[missing] = probs[covered[nearest]]
