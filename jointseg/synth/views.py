"""Single camera views cut from a room scan, as a depth camera delivers them: only what the
camera sees (inside its field of view, nearest surface per pixel), in the camera's own frame
(x right, y down, z forward; OpenCV's and PCL's convention).

They test what decides a scan's frame on the captures a room scan is not: one view of a wall,
a desk or a corner, tilted by however the camera was held.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jointseg.scan import Scan


@dataclass(frozen=True)
class CameraView:
    """A view and the truth about it.

    Attributes
    ----------
    scan : Scan
        The visible points in the camera's frame (colour and labels kept).
    up : ndarray of shape (3,)
        The room's up in the camera's frame.
    pitch_degrees, roll_degrees : float
        How the camera was held (pitch below 0: looking down).
    points : ndarray of shape (M,), int64
        The room's points the view holds, in the view's order.
    rotation, eye : ndarray of shape (3, 3) and (3,)
        The camera: view = (room - eye) @ rotation.T.
    """

    scan: Scan
    up: np.ndarray
    pitch_degrees: float
    roll_degrees: float
    points: np.ndarray
    rotation: np.ndarray
    eye: np.ndarray


def camera_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rows: the camera's x (right), y (down) and z (forward) axes in the room's frame (z up);
    angles in degrees."""
    y, p, r = np.radians([yaw, pitch, roll])
    forward = np.array([np.cos(p) * np.cos(y), np.cos(p) * np.sin(y), np.sin(p)])
    right = np.array([np.sin(y), -np.cos(y), 0.0])
    down = np.cross(forward, right)
    # roll about the viewing axis
    right, down = np.cos(r) * right + np.sin(r) * down, -np.sin(r) * right + np.cos(r) * down
    return np.stack([right, down, forward])


def visible(cam: np.ndarray, fov_degrees: tuple[float, float], pixels: int) -> np.ndarray:
    """Mask of the points (camera frame) inside the field of view and nearest in their pixel
    (within 5 % of that pixel's depth: a surface's own spread)."""
    z = cam[:, 2]
    tx, ty = np.tan(np.radians(np.asarray(fov_degrees) / 2.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cam[:, 0] / z / tx
        v = cam[:, 1] / z / ty
    inside = (z > 0.3) & (z < 8.0) & (np.abs(u) < 1) & (np.abs(v) < 1)
    idx = np.flatnonzero(inside)
    h = max(8, int(pixels * ty / tx))
    px = np.clip(((u[idx] + 1) / 2 * pixels).astype(np.int64), 0, pixels - 1)
    py = np.clip(((v[idx] + 1) / 2 * h).astype(np.int64), 0, h - 1)
    cell = py * pixels + px
    nearest = np.full(pixels * h, np.inf)
    np.minimum.at(nearest, cell, z[idx])
    keep = np.zeros(len(cam), dtype=bool)
    keep[idx[z[idx] <= nearest[cell] * 1.05 + 0.02]] = True
    return keep


def camera_view(
    room: Scan,
    rng: np.random.Generator,
    *,
    pitch_range: tuple[float, float] = (-25.0, 10.0),
    roll_range: tuple[float, float] = (-5.0, 5.0),
    fov_degrees: tuple[float, float] = (58.0, 45.0),
    pixels: int = 80,
    min_points: int = 2000,
    tries: int = 20,
) -> CameraView | None:
    """One view of ``room`` (z up, metres) from a camera held 1.0-1.7 m above the floor inside
    the room, looking at a random yaw; None when no try sees ``min_points``."""
    lo, hi = np.quantile(room.xyz, [0.02, 0.98], axis=0)
    for _ in range(tries):
        eye = np.array(
            [
                rng.uniform(lo[0] + 0.2 * (hi[0] - lo[0]), hi[0] - 0.2 * (hi[0] - lo[0])),
                rng.uniform(lo[1] + 0.2 * (hi[1] - lo[1]), hi[1] - 0.2 * (hi[1] - lo[1])),
                lo[2] + rng.uniform(1.0, 1.7),
            ]
        )
        pitch, roll = rng.uniform(*pitch_range), rng.uniform(*roll_range)
        rot = camera_rotation(rng.uniform(0, 360), pitch, roll)
        cam = (room.xyz - eye) @ rot.T
        keep = visible(cam, fov_degrees, pixels)
        if keep.sum() < min_points:
            continue
        scan = Scan(
            cam[keep],
            None if room.rgb is None else room.rgb[keep],
            None if room.labels is None else room.labels[keep],
            source_format="ply",
        )
        up = rot @ np.array([0.0, 0.0, 1.0])
        return CameraView(scan, up, float(pitch), float(roll), np.flatnonzero(keep), rot, eye)
    return None
