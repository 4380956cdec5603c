"""The clip box and the horizontal slice: which of a job's points every panel keeps.

viser draws what it is sent and has no clipping of its own (viser 1.1: no clipping planes on
point clouds; the camera's near and far planes only), so the viewer clips on the server: the
points outside the box or the height range are left out of the points it sends, the same rows
in every panel, and the panels are sent again when a range changes (:data:`SETTLE_S` after the
last change, so dragging a slider does not send every step).

The ranges are in metres as a surveyor reads them: x and y from the room's low corner (its
robust box: :func:`web.scene.robust_box`), heights above the floor
(:func:`web.picking.floor_height`), in the levelled frame the viewer shows.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import viser

from web.picking import floor_height
from web.scene import SceneData

#: Seconds without a further change before the panels are sent again.
SETTLE_S = 0.3
#: The sliders' step, metres.
STEP = 0.05
#: The slice a surveyor's plan cuts at, metres above the floor (clamped to the room).
DEFAULT_SLICE = (1.0, 1.5)

Ranges = tuple[float, ...]


@dataclass(frozen=True)
class Clip:
    """What the clip box and the slice keep: the rows of the scene data (bool), and whether an
    object's box (its corners) reaches into the kept region."""

    rows: np.ndarray
    box: Callable[[np.ndarray], bool]


@dataclass(frozen=True)
class ClipFrame:
    """Where the controls' metres sit in the scene: the room's low corner (x, y) and its floor
    (scene coordinates), and how far the sliders reach (x, y from the corner, z above the
    floor)."""

    corner: np.ndarray
    floor: float
    reach: np.ndarray

    @classmethod
    def of(cls, data: SceneData) -> ClipFrame:
        """The frame of a job's scene (centred on its robust box)."""
        half = np.asarray(data.extent, dtype=np.float64) / 2.0
        floor = floor_height(data.xyz[:, 2], data.fused)
        top = max(float(half[2]) - floor, STEP)
        reach = np.array([max(2 * half[0], STEP), max(2 * half[1], STEP), top])
        return cls(corner=-half, floor=floor, reach=np.ceil(reach / STEP) * STEP)

    def kept(self, xyz: np.ndarray, box: Ranges | None, heights: Ranges | None) -> np.ndarray:
        """Which of ``xyz`` (scene coordinates) lie inside the box (x0, x1, y0, y1, z0, z1) and
        the height range (low, high); both optional, (N,) bool."""
        keep = np.ones(xyz.shape[0], dtype=bool)
        low = np.array([self.corner[0], self.corner[1], self.floor])
        for axis, start, end in self._box_ranges(box):
            v = xyz[:, axis] - low[axis]
            keep &= (v >= start) & (v <= end)
        if heights is not None:
            z = xyz[:, 2] - self.floor
            keep &= (z >= heights[0]) & (z <= heights[1])
        return keep

    def overlaps(self, corners: np.ndarray, box: Ranges | None, heights: Ranges | None) -> bool:
        """Whether a box (its corners, scene coordinates) reaches into the kept region."""
        low = np.array([self.corner[0], self.corner[1], self.floor])
        lo, hi = corners.min(axis=0) - low, corners.max(axis=0) - low
        ranges = self._box_ranges(box)
        if heights is not None:
            ranges.append((2, heights[0], heights[1]))
        return all(hi[axis] >= start and lo[axis] <= end for axis, start, end in ranges)

    def _box_ranges(self, box: Ranges | None) -> list[tuple[int, float, float]]:
        """The box's (axis, start, end), a slider at its end open on that side: the box at
        full range keeps every point, the noise under the floor's median height and stray
        points beyond the room's robust box too (issue 63)."""
        if box is None:
            return []
        out = []
        for axis in range(3):
            start, end = float(box[2 * axis]), float(box[2 * axis + 1])
            out.append((
                axis,
                -np.inf if start <= STEP / 2 else start,
                np.inf if end >= float(self.reach[axis]) - STEP / 2 else end,
            ))  # fmt: skip
        return out


class ClipControls:
    """The *Clip and slice* folder: a slice and a clip box that apply to every panel.

    Parameters
    ----------
    gui : viser.GuiApi
    changed : callable
        Called (from a timer thread) once the ranges have settled after a change.
    box, heights : tuple of float, optional
        A link's clip box (six floats) and slice (two), switched on.
    """

    def __init__(
        self,
        gui: viser.GuiApi,
        changed: Callable[[], None],
        *,
        box: Ranges | None = None,
        heights: Ranges | None = None,
    ) -> None:
        self._changed = changed
        self._due: threading.Timer | None = None
        self._quiet = False
        self.frame: ClipFrame | None = None
        self._asked = (box, heights)
        with gui.add_folder("Clip and slice", expand_by_default=False):
            self.slicing = gui.add_checkbox(
                "Slice", heights is not None, hint="keep a height range in every panel"
            )
            self.heights = gui.add_multi_slider(
                "Heights (m above floor)", 0.0, 3.0, STEP, (1.0, 1.5), min_range=STEP
            )
            self.clipping = gui.add_checkbox(
                "Clip box", box is not None, hint="keep a box in every panel"
            )
            self.box = [
                gui.add_multi_slider(label, 0.0, 1.0, STEP, (0.0, 1.0), min_range=STEP)
                for label in ("Box x (m)", "Box y (m)", "Box z (m above floor)")
            ]
        for switch in (self.slicing, self.clipping):
            switch.on_update(lambda _: self._soon())
        for slider in (self.heights, *self.box):
            slider.on_update(lambda _: self._soon())

    def show_job(self, data: SceneData) -> None:
        """The sliders' reach for a job; its ranges those a link asked for (the first job), or
        the whole room and :data:`DEFAULT_SLICE` (within it)."""
        frame = self.frame = ClipFrame.of(data)
        box, heights = self._asked
        self._asked = (None, None)
        self._quiet = True
        try:
            for axis, slider in enumerate(self.box):
                top = float(frame.reach[axis])
                slider.max = top
                wanted = (0.0, top) if box is None else box[2 * axis : 2 * axis + 2]
                _set(slider, _within(wanted, top))
            self.heights.max = float(frame.reach[2])
            _set(self.heights, _within(heights or DEFAULT_SLICE, float(frame.reach[2])))
        finally:
            self._quiet = False

    def ranges(self) -> tuple[Ranges | None, Ranges | None]:
        """The clip box (x0, x1, y0, y1, z0, z1) and the slice (low, high) switched on."""
        box = tuple(float(v) for s in self.box for v in s.value) if self.clipping.value else None
        heights = tuple(float(v) for v in self.heights.value) if self.slicing.value else None
        return box, heights

    def kept(self, data: SceneData) -> Clip | None:
        """What every panel keeps: the job's rows, and whether an object's box is drawn; None
        when nothing is switched on."""
        box, heights = self.ranges()
        frame = self.frame
        if frame is None or (box is None and heights is None):
            return None
        return Clip(
            rows=frame.kept(data.xyz, box, heights),
            box=lambda corners: frame.overlaps(corners, box, heights),
        )

    def _soon(self) -> None:
        if self._quiet:
            return
        if self._due is not None:
            self._due.cancel()
        self._due = threading.Timer(SETTLE_S, self._changed)
        self._due.daemon = True
        self._due.start()


def _within(values: Ranges, top: float) -> tuple[float, float]:
    low = min(max(float(values[0]), 0.0), top - STEP)
    return low, min(max(float(values[1]), low + STEP), top)


def _set(handle: Any, value: tuple[float, float]) -> None:
    handle.value = value  # viser types it read-only
