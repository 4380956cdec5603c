"""Where the panels sit in the scene and where the camera looks from: plain geometry.

The panels are copies of one scan laid out left to right along x with gaps, so one camera
sees them all and orbiting moves every copy alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Gap between neighbouring panels as a fraction of a panel's width.
GAP_RATIO = 0.25
#: The camera looks down on the row from this elevation above the horizontal.
ELEVATION_DEG = 58.0
#: Vertical field of view the viewer sets, degrees.
FOV_DEG = 50.0


@dataclass(frozen=True)
class CameraPose:
    """A camera looking at the whole row of panels, z up."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov: float = math.radians(FOV_DEG)


def panel_offsets(extent: np.ndarray, count: int, *, gap_ratio: float = GAP_RATIO) -> np.ndarray:
    """Centre of each of ``count`` panels, left to right, the row centred on the origin.

    Parameters
    ----------
    extent : ndarray of shape (3,), metres
        Size of one panel (the scan's bounding box).
    count : int
    gap_ratio : float
        Gap between panels as a fraction of the panel width.

    Returns
    -------
    ndarray of shape (count, 3), metres
    """
    width = max(float(extent[0]), 1e-3)
    step = width * (1.0 + gap_ratio)
    offsets = np.zeros((count, 3))
    offsets[:, 0] = (np.arange(count) - (count - 1) / 2.0) * step
    return offsets


def title_position(extent: np.ndarray) -> tuple[float, float, float]:
    """Where a panel's title sits relative to the panel centre: above its far top edge."""
    return (0.0, float(extent[1]) / 2.0, float(extent[2]) / 2.0 + 0.05 * float(extent[2]))


def overview_camera(
    extent: np.ndarray,
    count: int,
    *,
    aspect: float = 16 / 9,
    gap_ratio: float = GAP_RATIO,
    elevation_deg: float = ELEVATION_DEG,
    fov_deg: float = FOV_DEG,
) -> CameraPose:
    """A camera in front of and above the row that fits every panel in the view.

    Parameters
    ----------
    extent : ndarray of shape (3,), metres
    count : int
        Panels in the row.
    aspect : float
        Canvas width / height.
    """
    width = max(float(extent[0]), 1e-3)
    row = count * width + (count - 1) * gap_ratio * width
    depth, height = float(extent[1]), float(extent[2])
    vfov = math.radians(fov_deg)
    hfov = 2.0 * math.atan(math.tan(vfov / 2.0) * aspect)
    # fit the row's width, then make sure the panels' depth fits vertically too
    distance = 0.55 * row / math.tan(hfov / 2.0) + depth / 2.0
    distance = max(distance, 0.6 * max(depth, height) / math.tan(vfov / 2.0) + depth / 2.0)
    elevation = math.radians(elevation_deg)
    look_at = (0.0, 0.0, -0.25 * height)
    position = (
        0.0,
        look_at[1] - distance * math.cos(elevation),
        look_at[2] + distance * math.sin(elevation),
    )
    return CameraPose(position=position, look_at=look_at, fov=vfov)
