"""What a correction covers: a segment or an object clicked, a region, or a lasso on screen.

A selection becomes one edit of :mod:`jointseg.labels.edits`, always about the whole result
(not only the sample the viewer draws):

- a segment clicked: ``segments`` (the method's own unit, every point of it);
- an object clicked: ``points``, every row of the result with that ``instance`` (the segments
  of its points when the result has no ``instance`` column);
- the clip box or the slice (:mod:`web.clipping`): a ``box`` in the file's coordinates when
  the file's axes are the shown axes (scaled or swapped), else the ``points`` inside;
- a lasso (the corners clicked on the canvas): ``points``, every row of the result whose
  position falls inside the polygon as the camera saw it, at any depth.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from jointseg.labels.edits import Edit
from web.clipping import ClipFrame, Ranges
from web.editing import Columns
from web.scene import SceneData

OFF = "Off (clicks use Click tools)"
SEGMENT, OBJECT = "Segment (click)", "Object (click)"
BOX, SLICE, LASSO = "Clip box region", "Slice region", "Lasso (click corners)"
MODES = (OFF, SEGMENT, OBJECT, BOX, SLICE, LASSO)
#: What the selection line says before anything is selected, by mode.
HINTS = {
    OFF: "Choose how to select, then a class.",
    SEGMENT: "Click a point: its segment is selected.",
    OBJECT: "Click a point of an object: the object is selected.",
    BOX: "The points inside the clip box (Clip and slice) are selected.",
    SLICE: "The points inside the slice's heights (Clip and slice) are selected.",
    LASSO: "Click the lasso's corners on the canvas (keep the camera still), then a class.",
}


@dataclass(frozen=True)
class Selection:
    """What the next class given applies to: ``what`` for the user, ``part`` the edit's
    selection (``segments``, ``points`` or ``box``)."""

    what: str
    part: dict[str, Any]

    def edit(self, cls: int) -> Edit:
        """The edit giving the selection class ``cls``."""
        return Edit.model_validate({**self.part, "label": cls})


def of_segment(data: SceneData, row: int) -> Selection:
    """The segment of a shown point."""
    seg = int(data.segments[row])
    shown = int(np.count_nonzero(data.segments == seg))
    return Selection(f"segment {seg} ({shown:,} points shown)", {"segments": [seg]})


def of_object(data: SceneData, columns: Columns, row: int) -> Selection | None:
    """The object of a shown point (None: the point is in no object)."""
    if data.instance is None or int(data.instance[row]) < 0:
        return None
    obj = int(data.instance[row])
    if columns.instance is None:
        segments = np.unique(data.segments[data.instance == obj])
        return Selection(f"object {obj}", {"segments": [int(s) for s in segments]})
    rows = np.flatnonzero(columns.instance == obj)
    return Selection(f"object {obj} ({rows.size:,} points)", {"points": rows.tolist()})


def of_region(
    data: SceneData,
    columns: Columns,
    box: Ranges | None,
    heights: Ranges | None,
    what: str,
) -> Selection | None:
    """The points inside the clip box or the slice (their controls' metres, :mod:`web.clipping`);
    None when the region is switched off or holds no point."""
    if box is None and heights is None:
        return None
    frame = ClipFrame.of(data)
    inside = frame.kept(data.shown_xyz(columns.xyz), box, heights)
    count = int(np.count_nonzero(inside))
    if count == 0:
        return None
    if _axis_aligned(data):
        lo, hi = _file_box(columns.xyz[inside])
        return Selection(f"{what} ({count:,} points)", {"box": {"min": lo, "max": hi}})
    return Selection(f"{what} ({count:,} points)", {"points": np.flatnonzero(inside).tolist()})


def _axis_aligned(data: SceneData) -> bool:
    """Whether a box of the shown frame is a box of the file's (no rotation but by quarter
    turns)."""
    if data.to_work is None:
        return True
    nonzero = np.abs(np.asarray(data.to_work, np.float64)[:3, :3]) > 1e-9
    return bool(np.all(nonzero.sum(axis=0) == 1) and np.all(nonzero.sum(axis=1) == 1))


def _file_box(xyz: np.ndarray) -> tuple[list[float], list[float]]:
    """The bounding box of points (file coordinates), a hair wider so that rounding through
    JSON keeps its edge points inside."""
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    pad = 1e-6 * np.maximum(1.0, np.abs(np.concatenate([lo, hi])).max())
    return (lo - pad).tolist(), (hi + pad).tolist()


def inside_lasso(points: np.ndarray, eye: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """Which of ``points`` (world coordinates, (N, 3)) a camera at ``eye`` sees inside the
    polygon its ``rays`` (the corners' directions, (K, 3), K >= 3) draw on screen, (N,) bool."""
    forward = rays.sum(axis=0)
    forward /= np.linalg.norm(forward)
    side = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(side) < 1e-6:  # looking straight down or up
        side = np.cross(forward, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    up = np.cross(side, forward)
    corners = np.stack([rays @ side, rays @ up], axis=1) / (rays @ forward)[:, None]
    rel = points - eye
    depth = rel @ forward
    ahead = depth > 1e-6
    safe = np.where(ahead, depth, 1.0)
    x, y = (rel @ side) / safe, (rel @ up) / safe
    inside = np.zeros(points.shape[0], bool)
    for (x0, y0), (x1, y1) in zip(corners, np.roll(corners, -1, axis=0), strict=True):
        crosses = (y0 > y) != (y1 > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            at = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        inside ^= crosses & (x < at)
    return inside & ahead


def of_lasso(
    data: SceneData,
    columns: Columns,
    eye: np.ndarray,
    rays: np.ndarray,
    offsets: dict[str, np.ndarray],
) -> Selection | None:
    """The points of the result inside a lasso, in the panel (of those at ``offsets``) where
    most shown points fall inside it; None when none does."""
    if rays.shape[0] < 3 or not offsets:
        return None
    counts = {k: int(inside_lasso(data.xyz + off, eye, rays).sum()) for k, off in offsets.items()}
    key = max(counts, key=lambda k: counts[k])
    if counts[key] == 0:
        return None
    world = data.shown_xyz(columns.xyz) + offsets[key]
    rows = np.flatnonzero(inside_lasso(world, eye, rays))
    if rows.size == 0:
        return None
    return Selection(
        f"lasso of {rays.shape[0]} corners ({rows.size:,} points)", {"points": rows.tolist()}
    )
