"""Picking and measuring in the viewer: which point a click's ray hits, distances, areas.

viser reports a click on the canvas as a ray in world coordinates; point clouds carry no
per-point hit test. The point hit is found here: of the points within ``tolerance`` of the ray
(a point is drawn as a square of about that size), the one nearest the camera's first
surface, so a click on a table top picks the table, not the floor seen through it.
"""

from __future__ import annotations

import numpy as np


def pick(
    xyz: np.ndarray, origin: np.ndarray, direction: np.ndarray, tolerance: float
) -> int | None:
    """Index of the point a ray hits, None when it passes every point by more than ``tolerance``.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
        Candidate points (only those drawn).
    origin, direction : ndarray of shape (3,)
        The click's ray, in the same coordinates.
    tolerance : float
        Largest distance from the ray that still counts as a hit.
    """
    if xyz.shape[0] == 0:
        return None
    d = np.asarray(direction, dtype=np.float64)
    d = d / max(float(np.linalg.norm(d)), 1e-12)
    rel = xyz.astype(np.float64) - np.asarray(origin, dtype=np.float64)
    along = rel @ d
    off = np.linalg.norm(rel - along[:, None] * d, axis=1)
    near = np.flatnonzero((off <= tolerance) & (along > 0))
    if near.size == 0:
        return None
    front = float(along[near].min())
    first = near[along[near] <= front + 2.0 * tolerance]  # the first surface along the ray
    return int(first[np.argmin(off[first])])


def polygon_area(corners: np.ndarray) -> float:
    """Area of a planar polygon in 3D (its corners in order), from Newell's normal; corners off
    the plane count by their projection on the best plane through them."""
    p = np.asarray(corners, dtype=np.float64)
    if p.shape[0] < 3:
        return 0.0
    q = np.roll(p, -1, axis=0)
    normal = 0.5 * np.cross(p, q).sum(axis=0)
    return float(np.linalg.norm(normal))


def floor_height(z: np.ndarray, fused: np.ndarray, floor_class: int = 1) -> float:
    """The floor's height in the levelled frame: the median of points labelled floor when there
    are enough of them, else the 1st percentile of every height."""
    on_floor = z[fused == floor_class]
    if on_floor.size >= 50:
        return float(np.median(on_floor))
    return float(np.quantile(z, 0.01)) if z.size else 0.0
