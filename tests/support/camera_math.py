"""A pinhole camera's arithmetic for the viewer's tests: where a point falls in the view.

A module of its own (not conftest) so test modules import it by name.
"""

from __future__ import annotations

import math

import numpy as np


def project(
    point: np.ndarray, position: np.ndarray, look_at: np.ndarray, fov: float, aspect: float
) -> tuple[float, float]:
    """Normalised image coordinates (-1..1 inside the view) of a pinhole camera, z up."""
    forward = (look_at - position) / np.linalg.norm(look_at - position)
    right = np.cross(forward, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = point - position
    depth = rel @ forward
    assert depth > 0, "point behind the camera"
    t = math.tan(fov / 2)
    return (rel @ right) / depth / (t * aspect), (rel @ up) / depth / t


def corners(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The 8 corners of a box, (8, 3)."""
    return np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1])
                     for z in (low[2], high[2])])  # fmt: skip
