"""The impure-segment guard (beyond the paper).

A majority vote helps where a segment holds one object and the network erred on a minority of
it; over a segment that mixes objects it overwrites the network's correct minority labels. Two
signs of such a segment are cheap to see in its vote histogram: no clear winner (the two largest
shares are close), and a huge segment (a wall plane holding a door and a board) whose majority
is not overwhelming. Such a segment is split into cubic cells that vote on their own, so the
vote stays local; a cell that still has no clear winner keeps the network's labels.
"""

from __future__ import annotations

import numpy as np

from jointseg.fusion.params import FusionParams
from jointseg.grouping import DENSE_SPAN_FACTOR, cell_keys, compact_ids


def top_two_shares(votes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vote shares, and the largest and second-largest share per row.

    Parameters
    ----------
    votes : ndarray of shape (S, C)
        Non-negative votes per segment and class.

    Returns
    -------
    shares : ndarray of shape (S, C), float64
        Rows sum to 1 (rows without votes are 0).
    first, second : ndarray of shape (S,), float64
    """
    total = votes.sum(axis=1, keepdims=True)
    shares = votes / np.maximum(total, 1e-12)
    if shares.shape[1] < 2:
        return shares, shares.max(axis=1, initial=0.0), np.zeros(len(shares))
    top = np.partition(shares, -2, axis=1)[:, -2:]
    return shares, top[:, 1], top[:, 0]


def impure(
    sizes: np.ndarray,
    first_share: np.ndarray,
    second_share: np.ndarray,
    *,
    n_points: int,
    params: FusionParams,
) -> np.ndarray:
    """Which segments the guard treats as mixing objects.

    Parameters
    ----------
    sizes : ndarray of shape (S,), int
        Points per segment.
    first_share, second_share : ndarray of shape (S,)
        Largest and second-largest vote share per segment.
    n_points : int
        Points in the scan.
    params : FusionParams
        ``guard_min_margin`` (no clear winner), ``guard_huge_fraction`` and
        ``guard_huge_min_share`` (huge and mixed).

    Returns
    -------
    ndarray of shape (S,), bool
    """
    no_winner = (first_share - second_share) < params.guard_min_margin
    huge = sizes > params.guard_huge_fraction * n_points
    return no_winner | (huge & (first_share < params.guard_huge_min_share))


def split_into_cells(
    xyz: np.ndarray, seg: np.ndarray, split: np.ndarray, cell_size: float
) -> tuple[np.ndarray, int]:
    """Voting units: each segment, except that split segments become one unit per cubic cell.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), metres
    seg : ndarray of shape (N,), int
        Segment 0..S-1 of every point.
    split : ndarray of shape (S,), bool
        Segments to split.
    cell_size : float
        Cell side in metres.

    Returns
    -------
    unit : ndarray of shape (N,), int64
        Unit of every point: unsplit segments keep their id, parts of split segments get ids
        from S on.
    n_units : int
    """
    n_seg = len(split)
    unit = seg.astype(np.int64, copy=True)
    members = np.flatnonzero(split[seg])
    if len(members) == 0:
        return unit, n_seg
    cells, n_cells = aligned_cell_keys(xyz[members], cell_size)
    # renumbering only the split points: one (segment, cell) pair per part
    _, part = compact_ids(seg[members].astype(np.int64) * n_cells + cells)
    unit[members] = n_seg + part
    return unit, n_seg + int(part.max()) + 1


def segment_cells(xyz: np.ndarray, seg: np.ndarray, cell_size: float) -> tuple[np.ndarray, int]:
    """Every segment cut into cubic cells of ``cell_size`` metres: one unit per (segment, cell).

    Returns
    -------
    unit : ndarray of shape (N,), int64
        Unit 0..U-1 of every point.
    n_units : int
    """
    cells, n_cells = aligned_cell_keys(xyz, cell_size)
    keys = seg.astype(np.int64, copy=False) * n_cells + cells
    n_seg = int(seg.max()) + 1 if len(seg) else 0
    if len(seg) == 0 or seg.min() < 0 or n_seg * n_cells > DENSE_SPAN_FACTOR * len(seg):
        ids, unit = compact_ids(keys)
        return unit, len(ids)
    # every key lies in [0, n_seg * n_cells): a unit's number is its key's rank among the
    # keys present (compact_ids's numbering), without the keys' least and largest
    present = np.zeros(n_seg * n_cells, dtype=bool)
    present[keys] = True
    rank = np.cumsum(present, dtype=np.int32 if len(present) < 2**31 else np.int64)
    unit = rank[keys].astype(np.int64)
    unit -= 1
    return unit, int(rank[-1])


def aligned_cell_keys(xyz: np.ndarray, size: float) -> tuple[np.ndarray, int]:
    """``cell_keys(xyz, size, aligned=True)`` to the bit, one coordinate at a time: the
    reductions over an (N, 3) array's first axis it would take are slow."""
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or len(xyz) == 0 or xyz.shape[1] == 0 or xyz.dtype != np.float64:
        return cell_keys(xyz, size, aligned=True)
    keys = np.zeros(len(xyz), dtype=np.int64)
    n_keys = 1
    for axis in range(xyz.shape[1]):
        cells = xyz[:, axis] / size
        np.floor(cells, out=cells)
        # whole numbers: their least is taken off exactly in float64, and float minima and
        # maxima are far cheaper than int64 ones
        lo, hi = cells.min(), cells.max()
        if not (np.isfinite(lo) and np.isfinite(hi)):
            return cell_keys(xyz, size, aligned=True)
        cells -= lo
        dim = int(hi - lo) + 1
        keys *= dim
        keys += cells.astype(np.int64)
        n_keys *= dim
    return keys, n_keys
