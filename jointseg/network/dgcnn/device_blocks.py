"""Torch twins of :mod:`jointseg.network.dgcnn.blocks`, so that on a GPU the columns, samples and
features are built where the network runs instead of making it wait for the CPU.

Each twin does the same index arithmetic in the same float64 precision as its numpy original,
so on the same points it returns the same columns and features. The random numbers are still
drawn with numpy's generator, in the original's order, and moved to the device: draws are cheap,
and the same seed then gives the same samples on either path.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from jointseg.network.dgcnn.blocks import EDGE_EPS


@dataclass(frozen=True)
class DeviceColumns:
    """:class:`~jointseg.network.dgcnn.blocks.Columns` as tensors on one device (same fields)."""

    points: torch.Tensor
    start: torch.Tensor
    weight: torch.Tensor

    @property
    def sizes(self) -> torch.Tensor:
        """Points per column, (C,) int64."""
        return self.start[1:] - self.start[:-1]

    def __len__(self) -> int:
        return len(self.start) - 1


def _ragged_arange(counts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For ``counts`` (N,): every (row, 0 .. counts[row] - 1) pair, rows in order."""
    row = torch.repeat_interleave(torch.arange(len(counts), device=counts.device), counts)
    first = torch.cumsum(counts, 0) - counts
    return row, torch.arange(len(row), device=counts.device) - first[row]


def _cells_1d(
    coord: torch.Tensor, count: int, size: float, stride: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Every (point, cell) pair along one axis, as ``blocks._cells_1d``."""
    lo = torch.ceil((coord - size - EDGE_EPS) / stride).long().clamp(0, count - 1)
    hi = torch.floor((coord + EDGE_EPS) / stride).long().clamp(0, count - 1)
    point, offset = _ragged_arange(hi - lo + 1)
    return point, lo[point] + offset


def column_blocks_torch(
    xy: torch.Tensor, *, size: float = 1.0, stride: float = 1.0, min_points: int = 100
) -> DeviceColumns:
    """:func:`~jointseg.network.dgcnn.blocks.column_blocks` on ``xy``'s device ((N, 2) float64,
    shifted so the minimum is 0); the same columns, points in the same order."""
    dev = xy.device
    if len(xy) == 0:
        empty = torch.zeros(0, dtype=torch.int64, device=dev)
        return DeviceColumns(empty, torch.zeros(1, dtype=torch.int64, device=dev), empty.double())
    limit = xy.max(dim=0).values.tolist()
    counts = [max(1, int(np.ceil((float(lim) - size) / stride)) + 1) for lim in limit]
    px, cx = _cells_1d(xy[:, 0], counts[0], size, stride)
    py, cy = _cells_1d(xy[:, 1], counts[1], size, stride)
    nx = torch.bincount(px, minlength=len(xy))
    ny = torch.bincount(py, minlength=len(xy))
    point, rank = _ragged_arange(nx * ny)
    x_start = torch.cumsum(nx, 0) - nx
    y_start = torch.cumsum(ny, 0) - ny
    col = cx[x_start[point] + torch.div(rank, ny[point], rounding_mode="floor")] * counts[1]
    col += cy[y_start[point] + rank % ny[point]]
    sizes = torch.bincount(col, minlength=counts[0] * counts[1])
    keep = sizes >= min_points
    if not bool(keep.any()):
        keep = sizes > 0
    mask = keep[col]
    point, col = point[mask], col[mask]
    col, order = torch.sort(col, stable=True)
    point = point[order]
    kept_sizes = torch.bincount(col, minlength=len(sizes))[keep]
    start = torch.cat([kept_sizes.new_zeros(1), torch.cumsum(kept_sizes, 0)])
    shares = torch.bincount(point, minlength=len(xy))
    return DeviceColumns(point, start, 1.0 / shares[point].double())


def _shuffle_within_columns(
    columns: DeviceColumns, col_of: torch.Tensor, rng: np.random.Generator
) -> torch.Tensor:
    """The column's points in a random order, as ``np.lexsort((rng.random(P), col_of))``: two
    stable sorts, the last by the primary key, order the points exactly as lexsort does."""
    keys = torch.from_numpy(rng.random(len(col_of))).to(col_of.device)
    by_key = torch.sort(keys, stable=True).indices
    perm = by_key[torch.sort(col_of[by_key], stable=True).indices]
    return columns.points[perm]


def _samples_per_column(
    columns: DeviceColumns, col_of: torch.Tensor, sizes: np.ndarray, num_points: int,
    coverage: float | None,
) -> np.ndarray:  # fmt: skip
    """How many samples each column gets (host array), as ``sample_columns`` counts them."""
    full = np.ceil(sizes / num_points).astype(np.int64)
    if coverage is None:
        return full
    owned_t = torch.zeros(len(sizes), dtype=torch.float64, device=col_of.device)
    owned = owned_t.index_add_(0, col_of, columns.weight).cpu().numpy()
    per_column = np.floor(coverage * owned / num_points + 0.5).astype(np.int64)
    return np.clip(per_column, 1, full)


def sample_columns_torch(
    columns: DeviceColumns, num_points: int, *, coverage: float | None, rng: np.random.Generator
) -> tuple[torch.Tensor, np.ndarray]:
    """:func:`~jointseg.network.dgcnn.blocks.sample_columns` on the columns' device.

    The per-column counts (a few thousand numbers) are worked out on the host; the point
    indices stay on the device. ``rng`` is drawn from exactly as the original draws, so the
    same generator state gives the same samples.

    Returns
    -------
    samples : Tensor of shape (S, num_points), int64, on the columns' device
    column : ndarray of shape (S,), int64
    """
    dev = columns.points.device
    sizes = columns.sizes.cpu().numpy()
    if len(sizes) == 0:
        return torch.zeros((0, num_points), dtype=torch.int64, device=dev), np.zeros(0, np.int64)
    sizes_t = torch.from_numpy(sizes).to(dev)
    col_of = torch.repeat_interleave(torch.arange(len(sizes), device=dev), sizes_t)
    shuffled = _shuffle_within_columns(columns, col_of, rng)
    per_column = _samples_per_column(columns, col_of, sizes, num_points, coverage)
    column = np.repeat(np.arange(len(sizes)), per_column)
    first = np.repeat(np.cumsum(per_column) - per_column, per_column)
    row = torch.from_numpy(np.arange(len(column)) - first).to(dev)
    local = row[:, None] * num_points + torch.arange(num_points, device=dev)
    size_np = sizes[column][:, None]
    draws = torch.from_numpy(rng.integers(0, size_np, local.shape)).to(dev)
    size = torch.from_numpy(size_np).to(dev)
    wrapped = torch.where(size >= num_points, local % size, draws)
    local = torch.where(local < size, local, wrapped)
    column_t = torch.from_numpy(column).to(dev)
    return shuffled[columns.start[column_t][:, None] + local], column


def block_features_torch(
    xyz: torch.Tensor,
    rgb: torch.Tensor,
    extent: torch.Tensor,
    *,
    size: float = 1.0,
    shift: torch.Tensor | None = None,
) -> torch.Tensor:
    """:func:`~jointseg.network.dgcnn.blocks.block_features` on ``xyz``'s device: (B, M, 9)
    float32 from float64 ``xyz`` (B, M, 3), ``rgb`` (B, M, 3) in 0-1 and ``extent`` (3,) or
    (B, 1, 3), computed in float64 as the original is, so the features are the same."""
    centred = xyz.clone()
    centred[..., :2] -= xyz[..., :2].amin(dim=1, keepdim=True) + size / 2
    normalised = (xyz if shift is None else xyz - shift) / extent
    return torch.cat([centred, rgb.double(), normalised], dim=-1).float()
