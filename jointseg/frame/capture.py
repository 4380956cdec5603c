"""What kind of capture a scan is: one camera's view, or a scan of a room (whole or partial).

A single depth-camera frame keeps the camera at its origin and every point in front of it,
inside the field of view: the points' directions from the origin fill a cone about +z (the
OpenCV/PCL convention: x right, y down, z forward) or about -z (OpenGL's: y up, looking along
-z). Such a view is a slice of a room seen from one side: its extremes along up are not floor
and ceiling, so the room-shaped evidence of the geometry weighs less, and the camera
convention itself says which way is up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: A camera view: at least this share of points in front of the origin ...
IN_FRONT = 0.995
#: ... within this angle (degrees) of the viewing axis (depth cameras see 60-90 degrees across,
#: the diagonal more; a fused fragment of a few frames a little more still), yet wider than
#: the narrowest camera's (a room far along z from a file's origin is no camera view) ...
MIN_CONE_DEGREES, MAX_CONE_DEGREES = 20.0, 78.0
#: ... and the nearest points between these shares of the median range: the camera does not
#: sit inside the cloud, and it sees near and far (a distant room is a narrow shell of ranges).
MIN_NEAR_SHARE, MAX_NEAR_SHARE = 0.05, 0.9
#: ... and it sees one surface along each ray (a depth image): at most this share of its
#: pixels (:data:`PIXEL_DEGREES` across) hold points more than :data:`LAYER_GAP` of their
#: range apart. A room seen from outside its own corner is hit twice along most rays.
MAX_LAYERED, PIXEL_DEGREES, LAYER_GAP = 0.33, 1.0, 0.15
#: Points the test looks at.
SAMPLE = 50_000


@dataclass(frozen=True)
class Capture:
    """The kind of capture, and the camera's viewing axis when it is one camera's view."""

    kind: str  # "camera view" | "scan"
    forward: str | None  # "+z" | "-z" for a camera view
    in_front: float
    cone_degrees: float

    @property
    def camera_up(self) -> str | None:
        """The file axis a camera view's up is nearest to (y down looking along +z; y up
        looking along -z)."""
        return {"+z": "-y", "-z": "+y"}.get(self.forward or "")

    def report(self) -> dict[str, Any]:
        """The ``frame.up.evidence.capture`` section of report.json."""
        return {
            "kind": self.kind,
            "forward": self.forward,
            "in_front": round(self.in_front, 4),
            "cone_degrees": round(self.cone_degrees, 1),
        }


def capture_kind(xyz: np.ndarray) -> Capture:
    """Tell a single camera view from a scan, from the points in the file's own coordinates."""
    step = max(1, len(xyz) // SAMPLE)
    p = np.asarray(xyz[::step], dtype=np.float64)
    r = np.linalg.norm(p, axis=1)
    ok = r > 0
    if ok.sum() < 20:
        return Capture("scan", None, 0.0, 180.0)
    p, r = p[ok], r[ok]
    cos = p[:, 2] / r
    best: Capture = Capture("scan", None, 0.0, 180.0)
    for sign, name in ((1.0, "+z"), (-1.0, "-z")):
        c = sign * cos
        in_front = float((c > 0).mean())
        cone = float(np.degrees(np.arccos(np.clip(np.quantile(c, 0.01), -1.0, 1.0))))
        near = float(np.quantile(r, 0.005) / max(np.median(r), 1e-12))
        if (
            in_front >= IN_FRONT
            and MIN_CONE_DEGREES <= cone <= MAX_CONE_DEGREES
            and MIN_NEAR_SHARE <= near <= MAX_NEAR_SHARE
            and layered(p * sign, r) <= MAX_LAYERED
        ):
            return Capture("camera view", name, in_front, cone)
        if in_front > best.in_front:
            best = Capture("scan", None, in_front, cone)
    return best


def layered(p: np.ndarray, r: np.ndarray) -> float:
    """The share of a depth image's pixels (rays from the origin, looking along +z) whose
    points lie at ranges more than :data:`LAYER_GAP` of their own apart."""
    front = p[:, 2] > 0
    p, r = p[front], r[front]
    if len(p) < 20:
        return 1.0
    step = np.tan(np.radians(PIXEL_DEGREES))
    u = np.floor(p[:, 0] / p[:, 2] / step).astype(np.int64)
    v = np.floor(p[:, 1] / p[:, 2] / step).astype(np.int64)
    pixel = (u - u.min()) * (int(v.max() - v.min()) + 1) + (v - v.min())
    order = np.argsort(pixel, kind="stable")
    pixel, r = pixel[order], r[order]
    starts = np.flatnonzero(np.r_[True, pixel[1:] != pixel[:-1]])
    counts = np.diff(np.r_[starts, len(pixel)])
    lo = np.minimum.reduceat(r, starts)
    hi = np.maximum.reduceat(r, starts)
    several = counts >= 2
    if not several.any():
        return 0.0
    return float(((hi - lo) > LAYER_GAP * lo)[several].mean())
