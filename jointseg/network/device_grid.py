"""The anchored grid sub-sample and the projection back to every point, in torch on a device.

Why: on a GPU the CPU's numpy/scipy versions (:func:`jointseg.network.anchored.anchored_cloud`,
:meth:`AnchoredCloud.nearest`) leave the device idle most of a whole-scan inference. These give
the same results: cell ids are computed with the same float64 operations, and sums are taken in
integer micrometres (and integer colours) in float64, which are exact in any order, so ids,
centroids and colours are bit for bit those of :func:`anchored_cloud`. The nearest centroid of a
point is searched by grid cells, exactly (see :func:`device_nearest`).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import torch

from jointseg.network.anchored import AXIS_BITS, QUANTUM, Projection

_MASK = (1 << AXIS_BITS) - 1
#: Points projected at once (about 1 GiB of temporaries).
CHUNK = 1 << 22


@dataclass(frozen=True)
class DeviceCloud:
    """An anchored grid sub-sample held on a device (the torch twin of ``AnchoredCloud``).

    Attributes
    ----------
    ids : (M,) int64 tensor, ascending packed cell ids
    xyz : (M, 3) float32 tensor, centroids relative to ``lower``
    rgb : (M, 3) float32 tensor in [0, 1]
    lower : ndarray of shape (3,), float64, the whole scan's lower corner
    grid : float, the cell side (m)
    """

    ids: torch.Tensor
    xyz: torch.Tensor
    rgb: torch.Tensor
    lower: np.ndarray
    grid: float

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    def nearest(self, xyz: np.ndarray | torch.Tensor) -> torch.Tensor:
        """Index of the sub-sampled point nearest each of ``xyz`` (N, 3) absolute, on the
        cloud's device (:func:`device_nearest`), in chunks of ``CHUNK`` points so the device
        memory stays bounded for scans of tens of millions of points."""
        parts = [device_nearest(self, xyz[s : s + CHUNK]) for s in range(0, len(xyz), CHUNK)]
        if not parts:
            return torch.zeros(0, dtype=torch.int64, device=self.xyz.device)
        return torch.cat(parts)

    def own_cell(self, xyz: np.ndarray | torch.Tensor) -> torch.Tensor:
        """Index of the sub-sampled point of each of ``xyz``'s own cell, as
        :meth:`AnchoredCloud.own_cell` (the nearest where the cloud lacks the cell)."""
        device = self.xyz.device
        query = torch.as_tensor(xyz, device=device).to(torch.float64)
        lower = torch.as_tensor(self.lower, dtype=torch.float64, device=device)
        wanted = _pack(_cells(query, self.grid, lower))
        idx = torch.searchsorted(self.ids, wanted).clamp_(max=max(len(self) - 1, 0))
        missing = torch.nonzero(self.ids[idx] != wanted).reshape(-1)
        if len(missing):
            idx[missing] = self.nearest(query[missing])
        return idx

    def rows(self, xyz: np.ndarray | torch.Tensor, projection: Projection) -> torch.Tensor:
        """The sub-sampled point each of ``xyz`` takes its output from (``projection``)."""
        return self.own_cell(xyz) if projection == "cell" else self.nearest(xyz)


def _cells(xyz: torch.Tensor, grid: float, lower: torch.Tensor) -> torch.Tensor:
    """(N, 3) int64 cell of each point: the same float64 operations as ``cell_ids``."""
    cells = torch.floor((xyz - lower) / grid).to(torch.int64)
    return cells.clamp_(0, _MASK)


def _pack(cells: torch.Tensor) -> torch.Tensor:
    return (cells[:, 0] << (2 * AXIS_BITS)) | (cells[:, 1] << AXIS_BITS) | cells[:, 2]


def _block_sums(
    xyz: torch.Tensor, rgb: torch.Tensor | None, grid: float, lower: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Unique cell ids and per-cell sums [count, x, y, z (µm), r, g, b] of one block, as
    ``_cell_sums`` (integer-valued float64: exact in any order)."""
    unique, inverse = torch.unique(_pack(_cells(xyz, grid, lower)), return_inverse=True)
    columns = torch.zeros((len(xyz), 7), dtype=torch.float64, device=xyz.device)
    columns[:, 0] = 1
    columns[:, 1:4] = torch.round((xyz - lower) / QUANTUM)
    if rgb is not None:
        columns[:, 4:7] = rgb.to(torch.float64)
    sums = torch.zeros((len(unique), 7), dtype=torch.float64, device=xyz.device)
    sums.index_add_(0, inverse, columns)
    return unique, sums


def device_anchored_cloud(
    blocks: Iterable[tuple[np.ndarray | torch.Tensor, np.ndarray | None]],
    grid: float,
    lower: np.ndarray,
    device: torch.device | str,
) -> DeviceCloud:
    """The grid sub-sample of points given in blocks, on ``device``: bit for bit the ids,
    centroids and colours of :func:`jointseg.network.anchored.anchored_cloud`."""
    lower = np.asarray(lower, dtype=np.float64)
    lower_t = torch.as_tensor(lower, dtype=torch.float64, device=device)
    ids_parts, sum_parts = [], []
    for xyz, rgb in blocks:
        if len(xyz):
            xyz_t = torch.as_tensor(xyz, device=device).to(torch.float64)
            rgb_t = None if rgb is None else torch.as_tensor(rgb, device=device)
            ids, sums = _block_sums(xyz_t, rgb_t, grid, lower_t)
            ids_parts.append(ids)
            sum_parts.append(sums)
    ids = torch.cat(ids_parts)
    sums = torch.cat(sum_parts)
    if len(ids_parts) > 1:
        ids, inverse = torch.unique(ids, return_inverse=True)
        merged = torch.zeros((len(ids), 7), dtype=torch.float64, device=sums.device)
        sums = merged.index_add_(0, inverse, sums)
    count = sums[:, 0:1]
    xyz_out = (sums[:, 1:4] / count * QUANTUM).to(torch.float32)
    rgb_out = (sums[:, 4:7] / count / 255.0).to(torch.float32)
    return DeviceCloud(ids, xyz_out, rgb_out, lower, float(grid))


def _ring(reach: int, device: torch.device) -> torch.Tensor:
    """(R, 3) cell offsets whose largest component is ``reach`` (the own cell for 0)."""
    steps = range(-reach, reach + 1)
    ring = [o for o in itertools.product(steps, repeat=3) if max(map(abs, o)) == reach]
    return torch.tensor(ring, dtype=torch.int64, device=device)


def _search_cells(
    cloud: DeviceCloud,
    cells: torch.Tensor,
    query: torch.Tensor,
    offsets: torch.Tensor,
    best: tuple[torch.Tensor, torch.Tensor],
) -> tuple[torch.Tensor, torch.Tensor]:
    """The nearest centroid so far (squared distance, index) after looking in the cells at
    ``offsets`` from each query's own cell (sorted ids and ``searchsorted``)."""
    best_d, best_i = best
    centroids = cloud.xyz
    m = len(cloud.ids)
    for offset in offsets:
        moved = cells + offset
        valid = ((moved >= 0) & (moved <= _MASK)).all(dim=1)
        wanted = _pack(moved.clamp(0, _MASK))
        pos = torch.searchsorted(cloud.ids, wanted).clamp_(max=m - 1)
        found = valid & (cloud.ids[pos] == wanted)
        diff = query - centroids[pos].to(torch.float64)
        sq = diff * diff
        d2 = sq[:, 0] + sq[:, 1] + sq[:, 2]
        better = found & (d2 < best_d)
        best_d = torch.where(better, d2, best_d)
        best_i = torch.where(better, pos, best_i)
    return best_d, best_i


def device_nearest(cloud: DeviceCloud, xyz: np.ndarray | torch.Tensor) -> torch.Tensor:
    """Index of the centroid nearest each point of ``xyz`` (N, 3) absolute, exactly as
    cKDTree over the float32 centroids finds it (ties may resolve differently).

    A centroid ``r`` cells from a point's own cell along some axis is at least ``r - 1`` cells
    away. So each point looks in the 27 cells around its own; those whose best is not nearer
    than one cell look in the ring two cells out (the own cell's centroid, when the cell is
    there, is within sqrt(3) cells); the rare rest (points far from every centroid) take a
    brute-force search. Distances in float64 from float32 coordinates, as cKDTree takes them.
    """
    device = cloud.xyz.device
    lower = torch.as_tensor(cloud.lower, dtype=torch.float64, device=device)
    points = torch.as_tensor(xyz, device=device).to(torch.float64)
    cells = _cells(points, cloud.grid, lower)
    query = (points - lower).to(torch.float32).to(torch.float64)
    # float32 rounding of coordinates can put a point slightly outside its own cell
    scale = float(query.abs().max()) if len(query) else 0.0
    slack = max(1e-3 * cloud.grid, 8 * float(np.finfo(np.float32).eps) * scale)
    best_d = torch.full((len(points),), torch.inf, dtype=torch.float64, device=device)
    best_i = torch.zeros(len(points), dtype=torch.int64, device=device)
    near = torch.cat([_ring(0, device), _ring(1, device)])
    best_d, best_i = _search_cells(cloud, cells, query, near, (best_d, best_i))
    farther = torch.nonzero(best_d >= (cloud.grid - slack) ** 2).squeeze(1)
    if len(farther):
        ring = _ring(2, device)
        best = (best_d[farther], best_i[farther])
        best_d[farther], best_i[farther] = _search_cells(
            cloud, cells[farther], query[farther], ring, best
        )
    lost = torch.nonzero(best_d >= (2 * cloud.grid - slack) ** 2).squeeze(1)
    if len(lost):
        best_i[lost] = _brute_nearest(cloud.xyz.to(torch.float64), query[lost])
    return best_i


def _brute_nearest(centroids: torch.Tensor, query: torch.Tensor) -> torch.Tensor:
    """Nearest centroid of each query by full distance rows (rare: points far from any
    centroid), in blocks of about 2**25 distances."""
    block = max(1, (1 << 25) // max(len(centroids), 1))
    parts = [
        torch.cdist(
            query[s : s + block], centroids, compute_mode="donot_use_mm_for_euclid_dist"
        ).argmin(dim=1)
        for s in range(0, len(query), block)
    ]
    return torch.cat(parts)
