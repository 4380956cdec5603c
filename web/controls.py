"""A tab's control panel: its folders and controls, and how they show a job.

Built once per tab; a job changes what the controls show (class buttons, tables, downloads),
never which controls exist. The view (:mod:`web.client_view`) wires what they do.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

import viser

from jointseg.classes import NUM_CLASSES, PALETTE, UNLABELLED, UNLABELLED_COLOUR
from server.results import Download
from web.camera import FIT_ALL
from web.clipping import ClipControls
from web.downloads import LABELS, NEEDS_LAYOUT, has_layout
from web.layout import VIEW_DIRECTIONS
from web.legend import class_title, confusion_html, iou_html, legend_html, present_classes
from web.objects_view import objects_html
from web.panels import POINT_SIZE
from web.scene import CONFIDENCE, ERRORS, FUSED, SEGMENTS, TRUTH, Panel, SceneData
from web.screenshot import SIZES
from web.tools import HINTS, MODES, PICK
from web.view_state import ViewState

PLACEHOLDER: str = "(choose a finished job)"
NO_JOBS: str = "(no finished jobs yet)"
#: A hidden class's button.
HIDDEN_CLASS = (222, 226, 230)
#: Optional panels and the label of the checkbox that shows each.
OPTIONAL = {TRUTH: "Ground truth panel", SEGMENTS: "Segments panel",
            CONFIDENCE: "Confidence panel", ERRORS: "Error map panel"}  # fmt: skip
ROW, SINGLE = "Row of panels", "One large panel"
#: The status line of a tab whose job was deleted.
GONE = (
    "**{name} was deleted** (or this key may no longer see it): nothing of it is shown. "
    "Choose another job."
)
#: Why the Downloads folder offers less than six files: no job shown, no report, no layout.
NO_DOWNLOADS = (
    "Show a job to download its files.",
    "This job has no report: no report, objects.json or IFC to download.",
    "This run found no objects or rooms: no objects.json or IFC to download.",
)
#: The download buttons, a row each: the scan's formats, the model, the report.
DOWNLOAD_GROUPS: dict[str, tuple[Download, ...]] = {
    "Points": ("ply", "las", "laz"),
    "Model": ("objects", "ifc"),
    "Report": ("report",),
}


class Controls:
    """Every control of one tab's panel, built from a link's view.

    Parameters
    ----------
    gui : viser.GuiApi
        The tab's control panel (``client.gui``).
    asked : ViewState
        The view a link asked for (its toggles are the controls' first values).
    max_points : int
        The viewer's cap of points per panel (the point budget's maximum).
    hidden : set of int
        The classes hidden (their buttons grey).
    clip_changed : callable
        Called once the clip box or the slice settled after a change.
    sign_out : callable, optional
        Ends the tab's sign-in session (a *Sign out* button only with one).
    """

    def __init__(
        self,
        gui: viser.GuiApi,
        asked: ViewState,
        max_points: int,
        *,
        hidden: set[int],
        clip_changed: Callable[[], None],
        sign_out: Callable[[], None] | None = None,
    ) -> None:
        self.gui = gui
        self.quiet = False  # set while the view changes controls itself
        self._job_and_display(asked, max_points, sign_out)
        with gui.add_folder("View"):
            self.views = gui.add_button_group("Camera", (FIT_ALL, *VIEW_DIRECTIONS))
            self.shot_size = gui.add_dropdown(
                "Screenshot size", tuple(SIZES), initial_value="2x canvas"
            )
            self.screenshot = gui.add_button("Screenshot (PNG)", icon=viser.Icon.CAMERA)
        self.clip = ClipControls(gui, clip_changed, box=asked.clip, heights=asked.slice_heights)
        self._tools_and_tables(asked)
        for cls in self.class_buttons:
            self.paint_class(cls, cls in hidden)

    def _job_and_display(
        self, asked: ViewState, max_points: int, sign_out: Callable[[], None] | None
    ) -> None:
        gui = self.gui
        with gui.add_folder("Job"):
            self.picker: viser.GuiDropdownHandle[str] = gui.add_dropdown("Job", (PLACEHOLDER,))
            self.refresh = gui.add_button("Refresh list", icon=viser.Icon.REFRESH)
            self.status = gui.add_markdown("No job shown.")
            self.address = gui.add_html("")  # keeps the browser's address following the view
            self.overlay = gui.add_html("")  # puts the legend over the canvas
            if sign_out is not None:
                out = gui.add_button("Sign out", icon=viser.Icon.LOGOUT, hint="end this sign-in")
                out.on_click(lambda _: sign_out())
        with gui.add_folder("Display"):
            self.layout = gui.add_dropdown(
                "Layout", (ROW, SINGLE), initial_value=SINGLE if asked.single else ROW
            )
            self.single = gui.add_dropdown("Panel", ("Fused labels",), visible=bool(asked.single))
            self.layout.on_update(lambda _: setattr(self.single, "visible", self.is_single))
            wanted = asked.panels if asked.panels is not None else frozenset({"truth"})
            self.panel_boxes = {
                panel: gui.add_checkbox(label, panel.key in wanted)
                for panel, label in OPTIONAL.items()
            }
            # the optional panels asked for (a job without ground truth unticks that box)
            self.wanted = {panel: panel.key in wanted for panel in OPTIONAL}
            size = asked.point_size or POINT_SIZE
            self.point_size = gui.add_slider(
                "Point size", 0.25, 8.0, 0.25, size, hint="multiple of the point spacing"
            )
            changed = asked.only_changed
            self.only_changed = gui.add_checkbox(
                "Only points changed by fusion", changed, hint="labels the fusion replaced"
            )
            top = max(max_points, 1000)
            self.budget = gui.add_number(
                "Point budget",
                int(min(asked.budget or top, top)),
                min=1000,
                max=top,
                step=1000,
                hint="most points per panel sent to this browser: lower it on a weak computer",
            )

    def _tools_and_tables(self, asked: ViewState) -> None:
        gui = self.gui
        with gui.add_folder("Click tools"):
            self.mode = gui.add_dropdown("Click to", MODES)
            self.answer = gui.add_markdown(HINTS[PICK])
            self.clear_marks = gui.add_button("Clear marks", icon=viser.Icon.ERASER)
        with gui.add_folder("Classes"):
            # one button per class in its palette colour: the toggle is the legend's swatch
            self.class_buttons = {
                cls: gui.add_button(class_title(cls), visible=False, hint="show or hide")
                for cls in (*range(NUM_CLASSES), UNLABELLED)
            }
            self.legend = gui.add_html("")
        with gui.add_folder("Scores (IoU)", visible=False) as self.scores_folder:
            self.scores = gui.add_html("")
        with gui.add_folder("Confusion", visible=False) as self.confusion_folder:
            self.confusion = gui.add_html("")
        with gui.add_folder("Objects and rooms", visible=False) as self.objects_folder:
            self.boxes = gui.add_checkbox(
                "Object boxes", asked.boxes, hint="in the fused panel, with their class"
            )
            self.objects_table = gui.add_html("")
            # one button per object (web.object_list): a click flies to it and selects it
            self.object_list = gui.add_folder("Object list", visible=False)
        with gui.add_folder("Downloads"):
            # the job page's six downloads, under the API's names (web.downloads)
            self.downloads_note = gui.add_markdown(NO_DOWNLOADS[0])
            self.download_groups = {
                kinds: gui.add_button_group(title, [LABELS[k] for k in kinds], visible=False)
                for title, kinds in DOWNLOAD_GROUPS.items()
            }

    @contextmanager
    def quietly(self) -> Iterator[None]:
        """Controls changed inside do not run their effects (the view changes them itself)."""
        self.quiet, was = True, self.quiet
        try:
            yield
        finally:
            self.quiet = was

    def set_quietly(self, handle: Any, value: Any) -> None:
        """Change a control without running its effects (viser types ``value`` read-only)."""
        with self.quietly():
            handle.value = value

    def on_panels(self, changed: Callable[[], None]) -> None:
        """Have a panel's box, ticked or unticked by the user, call ``changed``."""
        for panel, box in self.panel_boxes.items():

            def toggle(event: Any, panel: Panel = panel) -> None:
                if not self.quiet:
                    self.wanted[panel] = bool(event.target.value)
                    changed()

            box.on_update(toggle)

    def on_class(self, toggled: Callable[[int], None]) -> None:
        """Have a class's button call ``toggled`` with its class."""
        for cls, button in self.class_buttons.items():
            button.on_click(_calling(toggled, cls))

    def on_download(self, send: Callable[[Download], None]) -> None:
        """Have the download buttons call ``send`` with the kind of file clicked."""
        for kinds, group in self.download_groups.items():
            by_label = {LABELS[k]: k for k in kinds}

            def clicked(event: Any, by_label: dict[str, Download] = by_label) -> None:
                kind = by_label.get(str(event.target.value))
                if kind is not None:
                    send(kind)

            group.on_click(clicked)

    def paint_class(self, cls: int, hidden: bool) -> None:
        """A shown class's button in its palette colour with an open eye; a hidden one grey."""
        button = self.class_buttons[cls]
        if hidden:
            button.color, button.icon = HIDDEN_CLASS, viser.Icon.EYE_OFF
        else:
            rgb = UNLABELLED_COLOUR if cls < 0 else PALETTE[cls]
            button.color = (int(rgb[0]), int(rgb[1]), int(rgb[2]))
            button.icon = viser.Icon.EYE

    def show_job(self, data: SceneData, *, report: bool, single: str | None) -> None:
        """The tables, class buttons, panel choices and downloads of a job (``report``: it has
        a report; ``single``: a link's one panel)."""
        self.legend.content = legend_html(data.counts)
        present = present_classes(data.counts)
        for cls, button in self.class_buttons.items():
            button.visible = cls in present
        table = iou_html(data.report)
        self.scores.content = table or ""
        self.scores_folder.visible = table is not None
        listing = objects_html(data)
        self.objects_table.content = listing or ""
        self.objects_folder.visible = listing is not None
        matrix = None if data.truth is None else confusion_html(data.truth, data.fused)
        self.confusion.content = matrix or ""
        self.confusion_folder.visible = matrix is not None
        self.offer_downloads(data, report=report)
        self.clip.show_job(data)
        self.single.options = tuple(p.title for p in data.panels)
        chosen = next((p.title for p in data.panels if p.key == single), None)
        for panel, box in self.panel_boxes.items():
            box.disabled = panel not in data.panels
            self.set_quietly(box, panel in data.panels and self.wanted[panel])
        self.set_quietly(self.single, chosen or FUSED.title)

    def clear(self) -> None:
        """No job shown: its tables, class buttons and downloads go."""
        self.offer_downloads(None, report=False)
        self.scores_folder.visible = self.confusion_folder.visible = False
        self.objects_folder.visible = False
        self.legend.content = ""
        for button in self.class_buttons.values():
            button.visible = False
        self.status.content = "No job shown."
        self.answer.content = HINTS[PICK]

    def offer_downloads(self, data: SceneData | None, *, report: bool) -> None:
        """Show the rows of downloads the shown job has (viser cannot disable a button group),
        and say why any are missing."""
        layout = report and data is not None and has_layout(data.report)
        for kinds, group in self.download_groups.items():
            if NEEDS_LAYOUT & set(kinds):
                group.visible = layout
            elif "report" in kinds:
                group.visible = report
            else:
                group.visible = data is not None
        reason = 0 if data is None else 1 if not report else 2 if not layout else None
        self.downloads_note.content = "" if reason is None else NO_DOWNLOADS[reason]
        self.downloads_note.visible = reason is not None

    def look(self) -> tuple[bool, bool, float]:
        """How points are drawn: *only changed*, *Object boxes*, the point size (a multiple)."""
        return bool(self.only_changed.value), bool(self.boxes.value), float(self.point_size.value)

    def view_state(
        self,
        camera: ViewState,
        job_id: str | None,
        data: SceneData | None,
        hidden: set[int],
        max_points: int,
    ) -> ViewState:
        """The view as a link restores it: ``camera``'s part (:meth:`CameraFollow.link_state`)
        with the job, the classes hidden and every control's."""
        box, heights = self.clip.ranges()
        budget = int(self.budget.value)
        return replace(
            camera,
            job_id=job_id,
            hidden=frozenset(hidden),
            panels=frozenset(p.key for p, want in self.wanted.items() if want),
            only_changed=bool(self.only_changed.value),
            boxes=bool(self.boxes.value),
            point_size=float(self.point_size.value),
            single=None if data is None else self.panel_key(data),
            budget=None if budget >= max_points else budget,
            clip=box,
            slice_heights=heights,
        )

    @property
    def is_single(self) -> bool:
        """Whether one large panel is shown (not the row)."""
        return self.layout.value == SINGLE

    def panel_key(self, data: SceneData) -> str | None:
        """The key of the one large panel (None: the row is shown)."""
        if self.layout.value != SINGLE:
            return None
        return next((p.key for p in data.panels if p.title == self.single.value), None)

    def visible_panels(self, data: SceneData) -> tuple[Panel, ...]:
        """The panels shown, left to right."""
        if self.layout.value == SINGLE:
            chosen = [p for p in data.panels if p.title == self.single.value]
            return tuple(chosen[:1] or data.panels[2:3])
        return tuple(p for p in data.panels if p not in OPTIONAL or self.panel_boxes[p].value)


def _calling(action: Callable[[int], None], value: int) -> Callable[[Any], None]:
    """A click callback that calls ``action(value)``."""
    return lambda _: action(value)
