"""Where the panels sit in the scene and where the camera looks from: plain geometry.

The panels are copies of one scan laid out left to right with gaps, so one camera sees them
all and orbiting moves every copy alike: along x, or along y for the side elevation (seen from
+x, copies along x would hide behind the first).

The plan (*Top*) and the elevations (*Front*, *Side*) are what a surveyor reads as orthographic
views. viser's camera is a perspective camera only (viser 1.1: no orthographic projection, no
way to set one), so the presets stand in for one: the camera stands far away
(:func:`ortho_distance`) with a field of view of a degree or two, so that the scan's depth along
the view changes the scale by at most :data:`ORTHO_SCALE_ERROR`.
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


#: The presets' camera stands so far away that the depth of the scan along the view changes
#: the scale by at most this share (front to back).
ORTHO_SCALE_ERROR = 0.02
#: Nearest and farthest the presets' camera stands, metres (farther, the depth of a near plane
#: of 0.5 m grows coarse: a few centimetres at 600 m).
ORTHO_DISTANCES = (40.0, 600.0)
#: The camera's clipping planes outside the presets (viser's defaults).
NEAR, FAR = 0.01, 1000.0
#: The presets' near plane: far enough for depth to stay precise hundreds of metres away, and
#: nearer than 1 m, where viser draws the scene's background (beyond it, the background is
#: clipped and the canvas shows white).
ORTHO_NEAR = 0.5


@dataclass(frozen=True)
class CameraPose:
    """A camera looking at the whole row of panels, z up; its clipping planes."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    fov: float = math.radians(FOV_DEG)
    near: float = NEAR
    far: float = FAR


def row_axis(view: str | None) -> int:
    """The axis the panels are laid out along: y for the side elevation, else x."""
    return 1 if view == "Side" else 0


def panel_offsets(
    extent: np.ndarray, count: int, *, gap_ratio: float = GAP_RATIO, axis: int = 0
) -> np.ndarray:
    """Centre of each of ``count`` panels, left to right, the row centred on the origin.

    Parameters
    ----------
    extent : ndarray of shape (3,), metres
        Size of one panel (the room's robust box).
    count : int
    gap_ratio : float
        Gap between panels as a fraction of the panel width.
    axis : int
        Along x (0) or y (1: the side elevation, seen from +x).

    Returns
    -------
    ndarray of shape (count, 3), metres
    """
    width = max(float(extent[axis]), 1e-3)
    step = width * (1.0 + gap_ratio)
    offsets = np.zeros((count, 3))
    offsets[:, axis] = (np.arange(count) - (count - 1) / 2.0) * step
    return offsets


def title_position(extent: np.ndarray, axis: int = 0) -> tuple[float, float, float]:
    """Where a panel's title sits relative to the panel centre: above its far top edge (seen
    from the front, or from +x for a row along y)."""
    top = float(extent[2]) / 2.0 + 0.05 * float(extent[2])
    if axis == 1:
        return (-float(extent[0]) / 2.0, 0.0, top)
    return (0.0, float(extent[1]) / 2.0, top)


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
#: (the plan, north up) leans a hair towards -y so the orbit controls keep a defined up: 0.06°.
VIEW_DIRECTIONS: dict[str, tuple[float, float, float]] = {
    "Top": (0.0, -1e-3, 1.0),
    "Front": (0.0, -1.0, 0.0),
    "Side": (1.0, 0.0, 0.0),
}


def _row_corners(extent: np.ndarray, count: int, gap_ratio: float, axis: int) -> np.ndarray:
    """The 8 corners of the row's box, (8, 3), centred on the origin."""
    width = max(float(extent[axis]), 1e-3)
    half = np.asarray(extent, dtype=np.float64) / 2.0
    half[axis] = (count * width + (count - 1) * gap_ratio * width) / 2.0
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    return np.asarray(signs * half, dtype=np.float64)


def _screen_axes(back: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The image's right and up directions of a camera looking along ``-back``, z up."""
    right = np.cross(np.array([0.0, 0.0, 1.0]), back)
    if np.linalg.norm(right) < 1e-6:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    return right, np.cross(back, right)


def ortho_distance(depth: float) -> float:
    """How far the presets' camera stands from the middle of a scan ``depth`` metres deep along
    the view: its near face at ``depth / ORTHO_SCALE_ERROR``, within :data:`ORTHO_DISTANCES`."""
    low, high = ORTHO_DISTANCES
    return float(min(max(depth / ORTHO_SCALE_ERROR + depth / 2.0, low), high))


def ortho_camera(
    extent: np.ndarray,
    count: int,
    view: str,
    *,
    aspect: float = 16 / 9,
    gap_ratio: float = GAP_RATIO,
    margin: float = 1.06,
) -> CameraPose:
    """The plan or an elevation of the whole row (``view``: a key of :data:`VIEW_DIRECTIONS`),
    as near to orthographic as viser's perspective camera gets: from :func:`ortho_distance`,
    with the field of view that fits the row's box (its nearest face included) into the canvas,
    and a near plane far enough out for depth to stay precise that far away."""
    corners = _row_corners(extent, count, gap_ratio, row_axis(view))
    back = np.asarray(VIEW_DIRECTIONS[view], dtype=np.float64)
    back /= np.linalg.norm(back)
    right, screen_up = _screen_axes(back)
    along = corners @ back
    distance = ortho_distance(float(along.max() - along.min()))
    half = max(np.abs(corners @ screen_up).max(), np.abs(corners @ right).max() / aspect) * margin
    fov = 2.0 * math.atan(half / (distance - float(along.max())))
    x, y, z = (float(v) for v in back * distance)
    return CameraPose(
        position=(x, y, z),
        look_at=(0.0, 0.0, 0.0),
        fov=fov,
        near=ORTHO_NEAR,
        far=ortho_far(distance),
    )


def ortho_far(distance: float) -> float:
    """The presets' far plane: well beyond the scene, also when the user zooms out."""
    return max(FAR, 10.0 * distance)
