"""Classes a scan does not hold: found from the network's own outputs and taken out.

A network trained on one dataset, run on a scan from another sensor, scatters a few labels of
classes the room does not have (a handful of "beam" or "board" points in a ScanNet bedroom).
Each such class costs a whole class in a user's mIoU and shows as noise in the viewer. A class
the network itself gives to only a tiny share of the scan's cells is taken as absent, and those
cells take their next most likely class. The rule reads per-cell outputs of the whole scan, so
a tiled run gives the same answer as an untiled one.
"""

from __future__ import annotations

import numpy as np


def absent_classes(cell_probs: np.ndarray, min_share: float, max_cells: int) -> np.ndarray:
    """Boolean (C,): classes that win fewer than ``min_share`` of the cells and fewer than
    ``max_cells`` cells. Classes that win no cell count as absent too, so a cell that loses its
    class falls to a class the scan holds, not to a new scattered one."""
    counts = np.bincount(cell_probs.argmax(axis=1), minlength=cell_probs.shape[1])
    limit = min(min_share * len(cell_probs), max_cells)
    return counts < limit


def drop_absent(cell_probs: np.ndarray, min_share: float, max_cells: int) -> np.ndarray:
    """``cell_probs`` (M, C) with the absent classes' probabilities set to zero and each row
    renormalised; unchanged (the same array) when no class is absent."""
    absent = absent_classes(cell_probs, min_share, max_cells)
    winners = np.bincount(cell_probs.argmax(axis=1), minlength=cell_probs.shape[1]) > 0
    if not (absent & winners).any() or absent.all():
        return cell_probs
    kept = cell_probs.copy()
    kept[:, absent] = 0
    total = kept.sum(axis=1, keepdims=True)
    # a row whose whole mass was on absent classes keeps its original probabilities
    empty = total[:, 0] <= 0
    kept[empty] = cell_probs[empty]
    total[empty] = 1
    return (kept / total).astype(cell_probs.dtype, copy=False)
