"""What a click on the scene does: tell a point's labels, or measure a distance or an area.

One :class:`ClickTools` per browser tab. It keeps the points picked for the current
measurement, draws them as markers (and the lines between them) inside the panel they were
picked on, so they follow the panel when the layout changes, and writes the answer as
Markdown for the control panel. Distances are in the levelled metric frame the viewer shows,
so they are metres whatever the file's units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import viser

from jointseg.classes import NUM_CLASSES
from web.legend import class_title
from web.picking import floor_height, polygon_area
from web.render import Lines, Mark
from web.scene import SceneData

PICK, DISTANCE, AREA = "Pick a point", "Measure distance", "Measure area"
MODES = (PICK, DISTANCE, AREA)
#: What the answer says before the first click, by mode.
HINTS = {
    PICK: "Click a point in any panel.",
    DISTANCE: "Click two points.",
    AREA: "Click the corners of a planar area, in order.",
}
MARK_COLOUR = (255, 0, 200)


@dataclass(frozen=True)
class Picked:
    """A picked point: which panel it was clicked in, its row in the scene data, its shown
    position (scene coordinates, relative to the panel)."""

    panel: str
    index: int
    local: np.ndarray


def _label(labels: np.ndarray | None, index: int) -> str:
    if labels is None:
        return "-"
    value = int(labels[index])
    return class_title(value if 0 <= value < NUM_CLASSES else -1)


def describe(data: SceneData, index: int) -> str:
    """Markdown telling everything the result holds about one shown point."""
    x, y, z = data.file_xyz(data.xyz[index])
    conf = "" if data.confidence is None else f" (confidence {float(data.confidence[index]):.2f})"
    floor = floor_height(data.xyz[:, 2], data.fused)
    lines = [
        f"**Point** x {x:.3f}, y {y:.3f}, z {z:.3f} (file coordinates)",
        f"- network: {_label(data.network, index)}{conf}",
        f"- fused: {_label(data.fused, index)}",
    ]
    if data.truth is not None:
        lines.append(f"- ground truth: {_label(data.truth, index)}")
    lines.append(f"- segment: {int(data.segments[index])}")
    from web.objects_view import object_name, room_at

    obj, room = object_name(data, index), room_at(data, data.xyz[index])
    if obj is not None:
        lines.append(f"- object: {obj}")
    if room is not None:
        lines.append(f"- room: {room}")
    lines.append(f"- height above floor: {float(data.xyz[index, 2]) - floor:.3f} m")
    return "\n".join(lines)


class ClickTools:
    """The picked points of one tab and their markers.

    Parameters
    ----------
    scene : viser.SceneApi
        The tab's scene.
    root : str
        Scene path of the shown job; markers go below ``{root}/{panel}/``.
    """

    def __init__(self, scene: viser.SceneApi, root: str) -> None:
        self.scene = scene
        self.root = root
        self.mode = PICK
        self.points: list[Picked] = []
        self._nodes: list[viser.SceneNodeHandle] = []
        self._lines: viser.SceneNodeHandle | None = None
        self._serial = 0
        self._radius = 0.0  # the marks' radius, metres

    def set_mode(self, mode: str, answer: viser.GuiMarkdownHandle) -> None:
        """Switch to ``mode`` (a measurement starts again) and say what to click."""
        self.clear()
        self.mode = mode
        answer.content = HINTS[mode]

    def clear(self) -> None:
        """Forget the picked points and remove their markers."""
        for node in [*self._nodes, *([self._lines] if self._lines is not None else [])]:
            try:
                node.remove()
            except Exception:  # noqa: BLE001 - already gone with the job's root
                pass
        self._nodes, self._lines = [], None
        self.points = []

    def forget(self) -> None:
        """The job's nodes were removed with its root: drop the handles only."""
        self._nodes, self._lines = [], None
        self.points = []

    def add(self, data: SceneData, picked: Picked, marker_size: float) -> str:
        """Take one click; return the Markdown answer for the current mode."""
        if self.mode == PICK or (self.mode == DISTANCE and len(self.points) >= 2):
            self.clear()
        if self.points and self.points[0].panel != picked.panel:
            self.clear()  # a measurement stays within one panel
        self.points.append(picked)
        self._mark(picked, marker_size)
        if self.mode == PICK:
            return describe(data, picked.index)
        if self.mode == DISTANCE:
            return self._distance()
        return self._area()

    def _distance(self) -> str:
        if len(self.points) < 2:
            return "Distance: click a second point."
        a, b = (np.asarray(p.local, dtype=np.float64) for p in self.points[:2])
        d = b - a
        return (
            f"**Distance** {np.linalg.norm(d):.3f} m\n"
            f"- horizontal {np.hypot(d[0], d[1]):.3f} m, vertical {abs(d[2]):.3f} m"
        )

    def _area(self) -> str:
        n = len(self.points)
        if n < 3:
            return f"Area: {n} corner(s); click at least 3 corners on a plane, in order."
        corners = np.array([p.local for p in self.points], dtype=np.float64)
        perimeter = float(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1).sum())
        return f"**Area** {polygon_area(corners):.3f} m² ({n} corners, perimeter {perimeter:.3f} m)"

    def drawing(self, offsets: dict[str, np.ndarray]) -> tuple[list[Mark], list[Lines]]:
        """The marks (world position, radius, colour) and the measurement's lines as the tab
        draws them, in world coordinates (``offsets``: where each panel sits)."""
        if not self.points or self.points[0].panel not in offsets:
            return [], []
        offset = offsets[self.points[0].panel]
        corners = [np.asarray(p.local, np.float64) + offset for p in self.points]
        marks: list[Mark] = [(c, self._radius, MARK_COLOUR) for c in corners]
        if self.mode == PICK or len(corners) < 2:
            return marks, []
        pairs = [(corners[i], corners[i + 1]) for i in range(len(corners) - 1)]
        if self.mode == AREA and len(corners) >= 3:
            pairs.append((corners[-1], corners[0]))
        ends = np.asarray(pairs, np.float64)
        return marks, [Lines(ends, np.broadcast_to(MARK_COLOUR, ends.shape).copy(), 3.0)]

    def _mark(self, picked: Picked, size: float) -> None:
        self._radius = size
        self._serial += 1
        base = f"{self.root}/{picked.panel}/mark{self._serial}"
        self._nodes.append(
            self.scene.add_icosphere(
                base, radius=size, color=MARK_COLOUR, position=tuple(picked.local)
            )
        )
        if self.mode != PICK and len(self.points) >= 2:
            corners = [p.local for p in self.points]
            pairs = [(corners[i], corners[i + 1]) for i in range(len(corners) - 1)]
            if self.mode == AREA and len(corners) >= 3:
                pairs.append((corners[-1], corners[0]))
            if self._lines is not None:
                self._lines.remove()
            self._lines = self.scene.add_line_segments(
                base + "_lines",
                np.asarray(pairs, dtype=np.float32),
                MARK_COLOUR,
                thickness=3.0,
                thickness_units="screen",
            )
