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


#: Preset views: the direction the camera looks from, towards the row's centre (z up). "Top"
#: leans a hair towards -y so the orbit controls keep a defined up.
VIEW_DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "Top": (0.0, -1e-3, 1.0),
    "Front": (0.0, -1.0, 0.0),
    "Side": (1.0, 0.0, 0.0),
}


def view_camera(
    extent: np.ndarray,
    count: int,
    view: str,
    *,
    aspect: float = 16 / 9,
    gap_ratio: float = GAP_RATIO,
    fov_deg: float = FOV_DEG,
    margin: float = 1.08,
) -> CameraPose:
    """A camera looking from preset ``view`` (a key of :data:`VIEW_DIRECTIONS`) that fits the
    whole row: the row's bounding box projected on the image plane fits both fields of view.
    """
    width = max(float(extent[0]), 1e-3)
    row = count * width + (count - 1) * gap_ratio * width
    half = np.array([row, float(extent[1]), float(extent[2])]) / 2.0
    back = np.asarray(VIEW_DIRECTIONS[view], dtype=np.float64)
    back /= np.linalg.norm(back)
    up = np.array([0.0, 0.0, 1.0])
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-6:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    screen_up = np.cross(back, right)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    vfov = math.radians(fov_deg)
    hfov = 2.0 * math.atan(math.tan(vfov / 2.0) * aspect)
    # each corner needs the camera far enough back that it falls inside both fields of view
    depth = corners @ back
    need = np.maximum(
        np.abs(corners @ right) / math.tan(hfov / 2.0),
        np.abs(corners @ screen_up) / math.tan(vfov / 2.0),
    )
    distance = float(np.max(need + depth)) * margin
    position = tuple(float(v) for v in back * distance)
    return CameraPose(position=position, look_at=(0.0, 0.0, 0.0), fov=vfov)  # type: ignore[arg-type]
