"""The clickable object list: each object of the report with its class, size and height.

One button per object, in its class's colour, in the *Objects and rooms* folder; a click flies
the camera to the object and selects it in every panel (its box drawn in
:data:`SELECTED_COLOUR` around each copy). The buttons are made for each job and removed with
it, at most :data:`MAX_LISTED` of them (a report rarely holds more objects; the rest are
counted).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import viser

from jointseg.classes import CLASS_NAMES, PALETTE
from web.objects_view import CLUTTER, EDGES, objects_of
from web.scene import SceneData

#: Most objects listed (buttons) for one job.
MAX_LISTED = 300
#: The selected object's box, in every panel: an orange no class has.
SELECTED_COLOUR = (255, 120, 0)


@dataclass(frozen=True)
class ListedObject:
    """One object of the report as the list shows it; ``corners`` in scene coordinates."""

    id: int
    cls: str
    size: tuple[float, float, float]  # width, length, height, metres (the report's)
    above_floor: float  # its bottom's height above the floor, metres
    corners: np.ndarray  # (8, 3): bottom 0-3, top 4-7

    @property
    def name(self) -> str:
        """``chair 12``, as a click on its points names it."""
        return f"{self.cls} {self.id}"

    @property
    def label(self) -> str:
        """The button's text: class and id, size, height above the floor."""
        w, d, h = self.size
        return f"{self.name} · {w:.2f}×{d:.2f}×{h:.2f} m · {_metres(self.above_floor)} m up"

    @property
    def description(self) -> str:
        """Markdown for the answer beside the click tools."""
        w, d, h = self.size
        return (
            f"**Selected: {self.name}**\n"
            f"- size {w:.2f} × {d:.2f} m, {h:.2f} m high\n"
            f"- bottom {_metres(self.above_floor)} m above the floor"
        )

    @property
    def centre(self) -> np.ndarray:
        """The box's centre, scene coordinates."""
        return np.asarray(self.corners.mean(axis=0), dtype=np.float64)

    @property
    def radius(self) -> float:
        """Half the box's diagonal, metres."""
        return float(np.linalg.norm(self.corners.max(axis=0) - self.corners.min(axis=0)) / 2.0)

    def edges(self) -> np.ndarray:
        """The box's 12 edges, (12, 2, 3) float32, scene coordinates."""
        return np.asarray(self.corners[EDGES], dtype=np.float32)


def listed_objects(data: SceneData) -> list[ListedObject]:
    """The report's objects (fragments apart: their shape is not their class's), by class in
    palette order, then by id."""
    out = []
    for obj in objects_of(data):
        if not obj.get("plausible", True):
            continue
        corners = data.shown_xyz(np.asarray(obj["box"], dtype=np.float64))
        size = tuple(float(v) for v in obj.get("size") or np.ptp(corners, axis=0))
        out.append(
            ListedObject(
                id=int(obj["id"]),
                cls=str(obj["cls"]),
                size=(size[0], size[1], size[2]),
                above_floor=float(obj.get("height_above_floor") or 0.0),
                corners=corners,
            )
        )
    order = {name: i for i, name in enumerate(CLASS_NAMES)}
    return sorted(out, key=lambda o: (order.get(o.cls, len(order)), o.id))


class ObjectList:
    """The buttons of the shown job's objects.

    Parameters
    ----------
    gui : viser.GuiApi
        The tab's control panel.
    folder : viser.GuiFolderHandle
        Where the buttons go (made per job, removed with it).
    chosen : callable
        Called with the object whose button was clicked.
    """

    def __init__(
        self,
        gui: viser.GuiApi,
        folder: viser.GuiFolderHandle,
        chosen: Callable[[ListedObject], None],
    ) -> None:
        self.gui = gui
        self.folder = folder
        self._chosen = chosen
        self._buttons: list[viser.GuiButtonHandle | viser.GuiMarkdownHandle] = []
        self.objects: list[ListedObject] = []

    def show_job(self, data: SceneData) -> None:
        """One button per object of ``data`` (none and the folder hidden without objects)."""
        self.clear()
        self.objects = listed_objects(data)
        with self.folder:
            for obj in self.objects[:MAX_LISTED]:
                cls = CLASS_NAMES.index(obj.cls) if obj.cls in CLASS_NAMES else CLUTTER
                rgb = tuple(int(v) for v in PALETTE[cls])
                button = self.gui.add_button(obj.label, hint="fly to it and select it")
                button.color = (rgb[0], rgb[1], rgb[2])
                button.on_click(self._choosing(obj))
                self._buttons.append(button)
            if len(self.objects) > MAX_LISTED:
                more = len(self.objects) - MAX_LISTED
                self._buttons.append(self.gui.add_markdown(f"… and {more} more objects"))
        self.folder.visible = bool(self.objects)

    def _choosing(self, obj: ListedObject) -> Callable[[object], None]:
        return lambda _: self._chosen(obj)

    def clear(self) -> None:
        """No job: its buttons go."""
        for button in self._buttons:
            button.remove()
        self._buttons, self.objects = [], []
        self.folder.visible = False


def _metres(value: float) -> str:
    """Two decimals, never ``-0.00`` (a bottom a millimetre below the floor is on it)."""
    return f"{round(value, 2) + 0.0:.2f}"
