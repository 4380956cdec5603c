"""Inference that gives the same labels whether a scan is processed whole or in tiles.

RandLA-Net labels a scan through crops: a grid sub-sample, crop centres picked by the
'possibility' scheme, the K sub-sampled points nearest each centre, softmax outputs summed per
sub-sampled point. Three things made that depend on which points were loaded, and each is
pinned here to the whole scan:

- **The grid.** Cells are counted from the scan's lower corner (``lower``), and cell sums are
  taken in integer micrometres, which float64 adds exactly in any order, so a cell's centroid
  is the same bits whether it was computed from the whole scan, from a tile, or chunk by chunk.
- **The crops.** The crop plan (:class:`CropPlan`: centres, in order) is made once from the
  whole scan's sub-sample. A tile evaluates the crops whose centre lies in its core; a crop's
  members are the K nearest sub-sampled points, the same as in the whole scan when the crop's
  ball lies inside the tile's outer box (the plan records each crop's radius to check it).
- **The randomness inside a crop** (RandLA-Net's random sampling order) comes from a
  generator seeded with ``(seed, crop number)``, not from one stream shared by all crops.

Each tile then returns sums per sub-sampled cell keyed by :func:`cell_ids`; the merge adds them
over tiles, so a point next to a tile border is still averaged over every crop that saw it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial import cKDTree

from jointseg.boxes import in_box
from jointseg.grouping import compact_ids
from jointseg.network.presence import drop_absent
from jointseg.network.results import CellSums

#: Coordinates are summed in these units (micrometres): exact in float64 for any order.
QUANTUM = 1e-6
#: Bits per axis of a packed cell id (cells of 4 cm: 83 km per axis).
AXIS_BITS = 21
#: How points take the sub-sample's outputs (``RandLANetParams.projection``).
Projection = Literal["nearest", "cell"]


@dataclass(frozen=True)
class AnchoredCloud:
    """A grid sub-sample whose cells and centroids do not depend on which points were loaded.

    Attributes
    ----------
    ids : ndarray of shape (M,), int64
        Packed cell id of every sub-sampled point (ascending).
    xyz : ndarray of shape (M, 3), float32
        Centroids relative to ``lower``.
    rgb : ndarray of shape (M, 3), float32 in [0, 1]
    tree : cKDTree over ``xyz``
    lower : ndarray of shape (3,)
        The whole scan's lower corner.
    grid : float
        The cells' side (m).
    """

    ids: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray
    tree: cKDTree
    lower: np.ndarray
    grid: float

    def nearest(self, xyz: np.ndarray) -> np.ndarray:
        """Index of the sub-sampled point nearest each of ``xyz`` (N, 3) absolute."""
        query = (xyz - self.lower).astype(np.float32)
        _, idx = self.tree.query(query, k=1, workers=-1)
        return np.asarray(idx, dtype=np.int64)

    def own_cell(self, xyz: np.ndarray) -> np.ndarray:
        """Index of the sub-sampled point of each of ``xyz``'s own grid cell (a sorted lookup,
        a quarter of :meth:`nearest`'s time); a point whose cell the cloud lacks (one not among
        the points it was made from) takes its nearest."""
        wanted = cell_ids(xyz, self.grid, self.lower)
        idx = np.searchsorted(self.ids, wanted)
        np.minimum(idx, len(self.ids) - 1, out=idx)
        missing = np.flatnonzero(self.ids[idx] != wanted)
        if len(missing):
            idx[missing] = self.nearest(xyz[missing])
        return idx

    def rows(self, xyz: np.ndarray, projection: Projection) -> np.ndarray:
        """The sub-sampled point each of ``xyz`` takes its output from, by ``projection``
        (:attr:`~jointseg.network.randlanet.params.RandLANetParams.projection`)."""
        return self.own_cell(xyz) if projection == "cell" else self.nearest(xyz)


@dataclass(frozen=True)
class CropPlan:
    """Crop centres in evaluation order, chosen on the whole scan's sub-sample.

    Attributes
    ----------
    centres : ndarray of shape (C, 3), float32
        Relative to the scan's lower corner (as :attr:`AnchoredCloud.xyz`).
    radius : ndarray of shape (C,), float32
        Distance from each centre to its farthest member.
    crop_size : int
        Points per crop.
    """

    centres: np.ndarray
    radius: np.ndarray
    crop_size: int

    def __len__(self) -> int:
        return len(self.centres)


def cell_ids(xyz: np.ndarray, grid: float, lower: np.ndarray) -> np.ndarray:
    """Packed id of the ``grid``-sized cell of each point, counted from ``lower``."""
    return _pack(_grid_cells(xyz, grid, lower))


def _grid_cells(xyz: np.ndarray, grid: float, lower: np.ndarray) -> np.ndarray:
    """(N, 3) int64 cell of each point, counted from ``lower``, each axis within AXIS_BITS."""
    cells = np.floor((xyz - lower) / grid).astype(np.int64)
    np.clip(cells, 0, (1 << AXIS_BITS) - 1, out=cells)
    return cells


def _distinct_cells(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The packed ids of the distinct cells of ``cells`` (N, 3), ascending, and the row of each
    point's cell: ``np.unique(packed ids, return_inverse=True)``, the same arrays.

    Why: packed ids spread over 63 bits, so ``np.unique`` falls back to an argsort (0.6 s for
    5 M points); numbered densely over the block's own cell box in the same (x, y, z) order,
    they are grouped by :func:`~jointseg.grouping.compact_ids`' one packed sort instead.
    """
    first = cells.min(axis=0)
    span = cells.max(axis=0) - first + 1
    if float(span[0]) * float(span[1]) * float(span[2]) >= 2.0**62:  # an 83 km block: no room
        return np.unique(_pack(cells), return_inverse=True)
    local = cells - first
    dense = (local[:, 0] * span[1] + local[:, 1]) * span[2] + local[:, 2]
    distinct, inverse = compact_ids(dense)
    z = distinct % span[2]
    rest = distinct // span[2]
    distinct_cells = np.stack([rest // span[1], rest % span[1], z], axis=1) + first
    return _pack(distinct_cells), inverse


def _pack(cells: np.ndarray) -> np.ndarray:
    return (cells[:, 0] << (2 * AXIS_BITS)) | (cells[:, 1] << AXIS_BITS) | cells[:, 2]


def _cell_sums(
    xyz: np.ndarray, rgb: np.ndarray | None, grid: float, lower: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Unique cell ids and per-cell sums [count, x, y, z (µm), r, g, b] of one block."""
    unique, inverse = _distinct_cells(_grid_cells(xyz, grid, lower))
    q = np.rint((xyz - lower) / QUANTUM)
    columns = [np.ones(len(xyz)), q[:, 0], q[:, 1], q[:, 2]]
    colour = np.zeros((len(xyz), 3)) if rgb is None else rgb.astype(np.float64)
    columns += [colour[:, 0], colour[:, 1], colour[:, 2]]
    sums = np.column_stack(
        [np.bincount(inverse, weights=c, minlength=len(unique)) for c in columns]
    )
    return unique, sums


def anchored_cloud(
    blocks: Iterable[tuple[np.ndarray, np.ndarray | None]], grid: float, lower: np.ndarray
) -> AnchoredCloud:
    """The grid sub-sample of points given in blocks (a whole scan, a tile, or chunks).

    Parameters
    ----------
    blocks : iterable of (xyz (n, 3) absolute, rgb (n, 3) uint8 or None)
    grid : float
        Cell side (m).
    lower : ndarray of shape (3,)
        The whole scan's lower corner (every point at or above it).
    """
    lower = np.asarray(lower, dtype=np.float64)
    ids_parts, sum_parts = [], []
    for xyz, rgb in blocks:
        if len(xyz):
            ids, sums = _cell_sums(xyz, rgb, grid, lower)
            ids_parts.append(ids)
            sum_parts.append(sums)
    ids = np.concatenate(ids_parts)
    sums = np.concatenate(sum_parts)
    if len(ids_parts) > 1:
        ids, inverse = np.unique(ids, return_inverse=True)
        sums = np.column_stack(
            [np.bincount(inverse, weights=sums[:, c], minlength=len(ids)) for c in range(7)]
        )
    count = sums[:, 0:1]
    xyz = (sums[:, 1:4] / count * QUANTUM).astype(np.float32)
    rgb = (sums[:, 4:7] / count / 255.0).astype(np.float32)
    return AnchoredCloud(ids, xyz, rgb, cKDTree(xyz), lower, float(grid))


def plan_crops(
    cloud: AnchoredCloud, num_points: int, min_possibility: float, seed: int
) -> CropPlan:
    """Crop centres by the possibility scheme until every sub-sampled point is covered.

    A crop adds 1 - d²/r² to the possibility of each of its points (d: distance to the
    centre, r: the crop's radius); the next centre is the least covered point. Depends only
    on the sub-sample and the seed.
    """
    m = len(cloud.xyz)
    crop_size = min(num_points, max(m, 1024))
    rng = np.random.default_rng(seed)
    possibility = rng.random(m) * 1e-3
    centres: list[np.ndarray] = []
    radius: list[float] = []
    k = min(crop_size, m)
    while possibility.min() < min_possibility:
        centre = cloud.xyz[int(np.argmin(possibility))]
        dist, idx = cloud.tree.query(centre[None, :], k=k, workers=-1)
        d2 = np.asarray(dist).reshape(-1) ** 2
        idx = np.asarray(idx).reshape(-1)
        possibility[idx] += 1 - d2 / max(float(d2.max()), 1e-12)
        centres.append(centre)
        radius.append(float(np.sqrt(d2.max())))
    return CropPlan(
        np.array(centres, dtype=np.float32).reshape(-1, 3),
        np.array(radius, dtype=np.float32),
        crop_size,
    )


def crop_members(cloud: AnchoredCloud, plan: CropPlan, crop: int, seed: int) -> np.ndarray:
    """Indices into ``cloud`` of crop ``crop``'s points, in the crop's own random order."""
    m = len(cloud.xyz)
    k = min(plan.crop_size, m)
    _, idx = cloud.tree.query(plan.centres[crop][None, :], k=k, workers=-1)
    idx = np.asarray(idx).reshape(-1)
    rng = np.random.default_rng([seed, crop])
    if len(idx) < plan.crop_size:
        extra = rng.choice(idx, size=plan.crop_size - len(idx), replace=True)
        idx = np.concatenate([idx, extra])
    return rng.permutation(idx)


def crops_inside(
    plan: CropPlan, lower: np.ndarray, box_min: np.ndarray, box_max: np.ndarray
) -> np.ndarray:
    """Which crops' centres lie in the x-y box ``[box_min, box_max)`` (absolute)."""
    xy = plan.centres[:, :2].astype(np.float64) + lower[:2]
    return in_box(xy, box_min, box_max, open_upper=True)


def point_probs(
    cloud: AnchoredCloud,
    prob_sum: np.ndarray,
    seen: np.ndarray,
    xyz: np.ndarray,
    absent_share: float,
    absent_max_cells: int,
    projection: Projection,
) -> tuple[np.ndarray, np.ndarray]:
    """Every point's labels (N,) and probabilities (N, C) from the crops' sums per sub-sampled
    point: averaged, classes the scan does not hold taken out
    (:func:`~jointseg.network.presence.drop_absent`), then each point's nearest sub-sampled
    point's (or its own cell's: ``projection``)."""
    sub_probs = (prob_sum / np.maximum(seen, 1)[:, None]).astype(np.float32)
    sub_probs = drop_absent(sub_probs, absent_share, absent_max_cells)
    probs = sub_probs[cloud.rows(xyz, projection)]
    return probs.argmax(axis=1).astype(np.int32), probs


def tile_sums(
    cloud: AnchoredCloud,
    prob_sum: np.ndarray,
    seen: np.ndarray,
    xyz: np.ndarray,
    projection: Projection,
) -> CellSums:
    """A tile's sums per sub-sampled cell (those its crops saw), to be added over all tiles,
    and the cell each of its points ``xyz`` reads from (by ``projection``)."""
    touched = seen > 0
    return CellSums(
        ids=cloud.ids[touched],
        sums=prob_sum[touched],
        seen=seen[touched],
        point_cell=cloud.ids[cloud.rows(xyz, projection)],
    )
