"""What one browser tab sees: its job's panels in the scene and the controls beside them.

Each connected client has its own :class:`ClientView`, built from ``client.scene`` and
``client.gui``, so several people inspect different jobs at once. A job's points are sent once
per panel, split into one node per (class, changed by fusion) group: hiding a class, showing only
the changed points or resizing points are property updates, not new uploads. Switching jobs
removes the old nodes first, so neither the server nor the browser grows with the jobs viewed.

Every job is drawn below a scene path of its own (``/jointseg/<n>``): a node removed and added
again under the same name in one update can keep its old position in the browser, which laid
a three-panel job over a four-panel job's slots.

The browser's address follows the view (:mod:`web.view_state`): a copied link opens the same
job with the same camera, classes and toggles, and carries no key (whoever opens it signs in).
"""

from __future__ import annotations

import io
import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import viser

from jointseg.classes import NUM_CLASSES, PALETTE, UNLABELLED, UNLABELLED_COLOUR
from jointseg.exceptions import JointsegError
from server.api.results import Download
from server.messages import without_server_paths
from web.downloads import LABELS, NEEDS_LAYOUT, download_body, file_name, has_layout
from web.layout import (
    VIEW_DIRECTIONS,
    CameraPose,
    overview_camera,
    panel_offsets,
    title_position,
    view_camera,
)
from web.legend import class_title, confusion_html, iou_html, legend_html, present_classes
from web.memory import release_soon
from web.objects_view import box_segments, objects_html
from web.picking import pick
from web.scene import (
    CONFIDENCE,
    ERRORS,
    FUSED,
    NETWORK,
    SEGMENTS,
    TRUTH,
    Panel,
    SceneCache,
    SceneData,
    group_points,
)
from web.sources import JobEntry, JobSource
from web.tools import MODES, ClickTools, Picked
from web.view_state import ViewState, address_html, state_path

log = logging.getLogger(__name__)

ROOT = "/jointseg"
PLACEHOLDER: str = "(choose a finished job)"
NO_JOBS: str = "(no finished jobs yet)"
#: Classes hidden when a viewer opens: from above, the ceiling covers the room.
HIDDEN_BY_DEFAULT = frozenset({0})
#: Default point size as a multiple of the shown points' spacing.
POINT_SIZE = 2.0
#: Seconds the browser has to report back a camera pose the viewer set.
ECHO_WAIT_S = 3.0
#: Least seconds between two address updates while the camera moves.
ADDRESS_EVERY_S = 0.4
#: The scene's background: light blue-grey, so near-white clutter and the yellow ceiling show.
BACKGROUND = (205, 212, 220)
#: A hidden class's button.
HIDDEN_CLASS = (222, 226, 230)
#: Optional panels and the label of the checkbox that shows each.
OPTIONAL = {TRUTH: "Ground truth panel", SEGMENTS: "Segments panel",
            CONFIDENCE: "Confidence panel", ERRORS: "Error map panel"}  # fmt: skip
ROW, SINGLE = "Row of panels", "One large panel"
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
#: Which label set hides a panel's points with their class.
LABEL_KEY = {NETWORK.key: "network", CONFIDENCE.key: "network", TRUTH.key: "truth"}


class ClientView:
    """The per-client state and controls of the viewer.

    Parameters
    ----------
    client : viser.ClientHandle
    source : JobSource
        Finished jobs and their files.
    cache : SceneCache
        Loaded results shared by every client of one viewer (bounded).
    state : ViewState, optional
        The view a link asked for (classes, toggles, camera; its job is shown by the caller).
    sign_out : callable, optional
        Ends this tab's sign-in session (a *Sign out* button is shown only with one).
    """

    def __init__(
        self,
        client: viser.ClientHandle,
        source: JobSource,
        cache: SceneCache,
        state: ViewState | None = None,
        *,
        sign_out: Callable[[], None] | None = None,
    ) -> None:
        self.client = client
        self.source = source
        self.cache = cache
        self.asked = state or ViewState()
        self.sign_out = sign_out
        self.job_id: str | None = None
        self.data: SceneData | None = None
        self.hidden = set(HIDDEN_BY_DEFAULT if self.asked.hidden is None else self.asked.hidden)
        self.frames: dict[str, viser.FrameHandle] = {}
        self.nodes: dict[tuple[str, int, bool], viser.PointCloudHandle] = {}
        self.shown: np.ndarray | None = None  # rows of the scene data sent (point budget)
        self.boxes: dict[int, viser.LineSegmentsHandle] | None = None  # by class; None: not sent
        self._groups: dict[str, dict[tuple[int, bool], np.ndarray]] = {}
        self._root: viser.FrameHandle | None = None
        self._root_path = ROOT
        self._generation = 0
        self._labels: dict[str, str] = {}
        self._entries: dict[str, JobEntry] = {}
        self._lock = threading.RLock()
        self._quiet = False  # set while the view changes controls itself
        self._count = 0
        self._camera_hooked = False
        self._camera_auto = False
        self._camera_pose: CameraPose | None = None
        self._camera_aspect = 0.0
        self._camera_echoed = False
        self._camera_sent = 0.0
        self._address_serial = 0
        self._address_due: threading.Timer | None = None
        self._address_last = 0.0
        self._listed = False  # the picker has been sent a list
        self._list_failed = False
        client.scene.set_background_image(
            np.broadcast_to(np.array(BACKGROUND, np.uint8), (4, 4, 3)).copy(), format="png"
        )
        self.tools = ClickTools(client.scene, ROOT)
        self._build_gui()
        client.scene.on_click()(self._clicked)

    # ----------------------------------------------------------------- controls
    def _build_gui(self) -> None:
        self._build_job_and_display()
        self._build_tools_and_tables()
        self._wire()
        self.refresh_jobs()

    def _build_job_and_display(self) -> None:
        gui = self.client.gui
        asked = self.asked
        with gui.add_folder("Job"):
            self.picker: viser.GuiDropdownHandle[str] = gui.add_dropdown("Job", (PLACEHOLDER,))
            self.refresh = gui.add_button("Refresh list", icon=viser.Icon.REFRESH)
            self.status = gui.add_markdown("No job shown.")
            self.address = gui.add_html("")
            if self.sign_out is not None:
                signing_out = self.sign_out
                out = gui.add_button("Sign out", icon=viser.Icon.LOGOUT, hint="end this sign-in")
                out.on_click(lambda _: signing_out())
        with gui.add_folder("Display"):
            self.layout = gui.add_dropdown(
                "Layout", (ROW, SINGLE), initial_value=SINGLE if asked.single else ROW
            )
            self.single = gui.add_dropdown("Panel", ("Fused labels",), visible=bool(asked.single))
            wanted = asked.panels if asked.panels is not None else frozenset({"truth"})
            self.panel_boxes = {
                panel: gui.add_checkbox(label, panel.key in wanted)
                for panel, label in OPTIONAL.items()
            }
            self._wanted = {panel: panel.key in wanted for panel in OPTIONAL}
            self.truth_box = self.panel_boxes[TRUTH]
            self.segments_box = self.panel_boxes[SEGMENTS]
            self.point_size = gui.add_slider(
                "Point size",
                0.25,
                8.0,
                0.25,
                asked.point_size or POINT_SIZE,
                hint="multiple of the point spacing",
            )
            self.only_changed = gui.add_checkbox(
                "Only points changed by fusion",
                asked.only_changed,
                hint="labels the fusion replaced",
            )
            top = max(self.cache.max_points, 1000)
            self.budget = gui.add_number(
                "Point budget",
                int(min(asked.budget or top, top)),
                min=1000,
                max=top,
                step=1000,
                hint="most points per panel sent to this browser: lower it on a weak computer",
            )

    def _build_tools_and_tables(self) -> None:
        gui = self.client.gui
        with gui.add_folder("View"):
            self.views = gui.add_button_group("Camera", ("Fit all", *VIEW_DIRECTIONS))
            self.screenshot = gui.add_button("Screenshot (PNG)", icon=viser.Icon.CAMERA)
        with gui.add_folder("Click tools"):
            self.mode = gui.add_dropdown("Click to", MODES)
            self.answer = gui.add_markdown("Click a point in any panel.")
            self.clear_marks = gui.add_button("Clear marks", icon=viser.Icon.ERASER)
        # built once and updated per job (no GUI elements are created or removed per job)
        with gui.add_folder("Classes"):
            # one button per class in its palette colour: the toggle is the legend's swatch
            self.class_buttons = {
                cls: gui.add_button(class_title(cls), visible=False, hint="show or hide")
                for cls in (*range(NUM_CLASSES), UNLABELLED)
            }
            for cls in self.class_buttons:
                self._paint_class(cls)
            self.legend = gui.add_html("")
        with gui.add_folder("Scores (IoU)", visible=False) as self.scores_folder:
            self.scores = gui.add_html("")
        with gui.add_folder("Confusion", visible=False) as self.confusion_folder:
            self.confusion = gui.add_html("")
        with gui.add_folder("Objects and rooms", visible=False) as self.objects_folder:
            self.boxes_box = gui.add_checkbox(
                "Object boxes", self.asked.boxes, hint="in the fused panel, with their class"
            )
            self.objects_table = gui.add_html("")
        with gui.add_folder("Downloads"):
            # the job page's six downloads, under the API's names (web.downloads)
            self.downloads_note = gui.add_markdown(NO_DOWNLOADS[0])
            self.download_groups = {
                kinds: gui.add_button_group(title, [LABELS[k] for k in kinds], visible=False)
                for title, kinds in DOWNLOAD_GROUPS.items()
            }

    def _wire(self) -> None:
        self.picker.on_update(lambda _: self._picked())
        self.refresh.on_click(lambda _: self.refresh_jobs())
        self.layout.on_update(lambda _: self._layout_changed())
        self.single.on_update(lambda _: self._changed(self.redraw))
        for panel, box in self.panel_boxes.items():
            box.on_update(self._panel_toggle(panel))
        self.point_size.on_update(lambda _: self._changed(self._resize_points))
        self.only_changed.on_update(lambda _: self._changed(self._apply_visibility))
        self.budget.on_update(lambda _: self._changed(self._rebudget))
        self.views.on_click(lambda event: self.set_view(str(event.target.value)))
        self.screenshot.on_click(lambda _: self.send_screenshot())
        self.mode.on_update(lambda _: self._mode_changed())
        self.boxes_box.on_update(lambda _: self._changed(self._show_boxes))
        self.clear_marks.on_click(lambda _: self._clear_marks())
        for cls, button in self.class_buttons.items():
            button.on_click(self._class_toggle(cls))
        for kinds, group in self.download_groups.items():
            group.on_click(self._download_click(kinds))

    def _changed(self, action: Callable[[], None]) -> None:
        """A control the user changed: act, then write the view into the address."""
        if self._quiet:
            return
        action()
        self.sync_address()

    def refresh_jobs(self) -> None:
        """Reload the job picker's list (finished jobs, newest first), keeping the current
        choice; then, if the shown job has gone (deleted, or no longer this key's), say so.

        The viewer calls this every :data:`web.viewer.LIST_EVERY_S` seconds, so jobs deleted
        or finished elsewhere leave or join the list without a reload; the picker is sent again
        only when its list changed (an open dropdown is not redrawn under the mouse).
        """
        try:
            jobs = list(self.source.finished_jobs())
        except Exception:  # the list is best effort: a database hiccup must not kill the tab
            if not self._list_failed:
                log.exception("listing finished jobs failed")
            self._list_failed = True
            return  # keep the last list: a hiccup is no reason to call every job gone
        self._list_failed = False
        with self._lock:
            known = dict(self._entries)
            labels = {job.label: job.id for job in jobs}
            self._entries = {job.id: job for job in jobs}
            if labels != self._labels or not self._listed:
                self._labels, self._listed = labels, True
                current = self.picker.value
                self._quiet, was = True, self._quiet
                try:  # a choice that left the list falls back to the placeholder, quietly
                    self.picker.options = (PLACEHOLDER if jobs else NO_JOBS, *labels)
                finally:
                    self._quiet = was
                if current in labels:
                    self._set_value(self.picker, current)
            if self.job_id is not None and self.job_id not in self._entries:
                self._check_shown(self.job_id, known.get(self.job_id))

    def _check_shown(self, job_id: str, entry: JobEntry | None) -> None:
        """The shown job is not in the list: beyond the list's length, or gone. When gone, its
        panels are removed and the tab says so, rather than showing a job that is no more."""
        try:
            self.source.result_path(job_id)
            return  # still there (the list holds the newest jobs only)
        except JointsegError as exc:
            log.info("client %d: job %s is gone: %s", self.client.client_id, job_id, exc)
        name = f"{entry.filename} [{job_id[:8]}]" if entry is not None else job_id
        self.clear()
        self.status.content = (
            f"**{name} was deleted** (or this key may no longer see it): nothing of it is "
            "shown. Choose another job."
        )
        self.client.add_notification(
            "Job deleted", f"{name} is no longer on the service.", color="red"
        )
        self.sync_address()

    def _set_value(self, handle: Any, value: Any) -> None:
        """Change a control without running its callbacks' effects."""
        self._quiet, was = True, self._quiet
        try:
            handle.value = value
        finally:
            self._quiet = was

    def _picked(self) -> None:
        if self._quiet:
            return
        job_id = self._labels.get(self.picker.value)
        if job_id is not None and job_id != self.job_id:
            self.show_job(job_id)

    def select(self, job_id: str) -> None:
        """Show ``job_id`` and select it in the picker (used for links to one job)."""
        label = next((lab for lab, i in self._labels.items() if i == job_id), None)
        if label is None:
            self.refresh_jobs()
            label = next((lab for lab, i in self._labels.items() if i == job_id), None)
        if label is not None:
            self._set_value(self.picker, label)
        self.show_job(job_id, camera=self.asked.camera)

    # -------------------------------------------------------------------- jobs
    def show_job(self, job_id: str, *, camera: tuple[float, ...] | None = None) -> bool:
        """Replace the scene with ``job_id``'s panels.

        Parameters
        ----------
        camera : tuple of 6 floats, optional
            Camera position and look-at to start from (a link's); else the overview.

        Returns
        -------
        bool
            False (and a notification in the browser) when the job cannot be shown.
        """
        with self._lock:
            started = time.perf_counter()
            try:
                result = self.source.result_path(job_id)
                data = self.cache.load(result, self.source.report_path(job_id))
            except (JointsegError, OSError) as exc:
                log.warning("cannot show job %s: %s", job_id, exc)
                self.client.add_notification(
                    "Cannot show this job", str(exc), color="red", auto_close_seconds=10.0
                )
                return False
            loaded = time.perf_counter()
            self.clear()
            self.job_id, self.data = job_id, data
            self._select_points(data)
            with self.client.atomic():
                self._generation += 1
                self._root_path = f"{ROOT}/{self._generation}"
                self._root = self.client.scene.add_frame(self._root_path, show_axes=False)
                self.tools.root = self._root_path
                self._update_job_gui(data)
                self.redraw(camera=camera is None)
                if camera is not None:
                    self._place_camera(camera[:3], camera[3:])
            self.client.flush()
            self.sync_address()
            release_soon()  # the previous job's clouds and the reading's buffers are freed
            log.info(
                "client %d shows %s: loaded in %.2f s, sent in %.2f s",
                self.client.client_id,
                job_id,
                loaded - started,
                time.perf_counter() - loaded,
            )
            return True

    def _select_points(self, data: SceneData) -> None:
        """The rows sent to this browser (at most the point budget per panel) and their groups."""
        budget, n = int(self.budget.value), data.xyz.shape[0]
        # an even random subset of what the viewer loaded (itself thinned evenly for big
        # files): exactly the budget, the same rows every time for one budget
        rng = np.random.default_rng(budget)
        self.shown = None if n <= budget else np.sort(rng.choice(n, budget, replace=False))

        def sel(a: np.ndarray) -> np.ndarray:
            return a if self.shown is None else a[self.shown]

        changed = sel(data.changed)
        self._groups = {
            "network": group_points(sel(data.network), changed),
            "fused": group_points(sel(data.fused), changed),
        }
        if data.truth is not None:
            self._groups["truth"] = group_points(sel(data.truth), changed)

    def _rows(self, positions: np.ndarray) -> np.ndarray:
        """Rows of the scene data of positions among the points sent."""
        return positions if self.shown is None else self.shown[positions]

    def clear(self) -> None:
        """Remove the shown job's nodes and job-specific controls."""
        with self._lock:
            if self._root is not None:
                self._root.remove()  # removes every panel node below it
            self.tools.forget()
            self._root, self.job_id, self.data, self.shown = None, None, None, None
            self.frames, self.nodes, self._groups = {}, {}, {}
            self._offer_downloads(None)
            self.scores_folder.visible = self.confusion_folder.visible = False
            self.objects_folder.visible = False
            self.boxes = None
            self.legend.content = ""
            for button in self.class_buttons.values():
                button.visible = False
            self.status.content = "No job shown."
            self.answer.content = "Click a point in any panel."

    def _update_job_gui(self, data: SceneData) -> None:
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
        for panel, box in self.panel_boxes.items():
            available = panel in data.panels
            box.disabled = not available
            self._set_value(box, available and self._wanted[panel])
        titles = [p.title for p in data.panels]
        self.single.options = tuple(titles)
        asked = next((p.title for p in data.panels if p.key == self.asked.single), None)
        self._set_value(self.single, asked or FUSED.title)
        self._offer_downloads(data)

    def _offer_downloads(self, data: SceneData | None) -> None:
        """Show the rows of downloads the shown job has (viser cannot disable a button group),
        and say why any are missing."""
        report = data is not None and self.source.report_path(self.job_id or "") is not None
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

    def _status_line(self) -> None:
        """How many points the browser draws now, of how many the scan has."""
        data = self.data
        if data is None:
            return
        panels = self.visible_panels()
        panel = (
            panels[0]
            if len(panels) == 1
            else next((p for p in panels if p.key == "fused"), panels[0] if panels else None)
        )
        drawn = 0 if panel is None else self._drawn(panel)
        sent = data.xyz.shape[0] if self.shown is None else self.shown.size
        notes = []
        if data.voxel is not None:
            notes.append(f"voxel {data.voxel * 100:.1f} cm")
        if sent < data.xyz.shape[0]:
            notes.append(f"budget {sent:,} of {data.xyz.shape[0]:,} loaded")
        note = f" ({', '.join(notes)})" if notes else ""
        where = "" if panel is None else f" in {panel.title}"
        entry = self._entries.get(self.job_id or "")
        name = f"{entry.filename} [{entry.id[:8]}]" if entry is not None else self.job_id
        self.status.content = (
            f"**{name}**: {drawn:,} of {data.total_points:,} points shown{where}{note}."
        )

    def _drawn(self, panel: Panel) -> int:
        groups = self._groups.get(LABEL_KEY.get(panel.key, "fused"), {})
        return sum(idx.size for (cls, ch), idx in groups.items() if self._node_visible(cls, ch))

    def _class_toggle(self, cls: int) -> Callable[[Any], None]:
        def toggle(_: Any) -> None:
            with self._lock:
                if cls in self.hidden:
                    self.hidden.discard(cls)
                else:
                    self.hidden.add(cls)
                self._paint_class(cls)
                self._apply_visibility()
            self.sync_address()

        return toggle

    def _paint_class(self, cls: int) -> None:
        """A shown class's button in its palette colour with an open eye; a hidden one grey."""
        button = self.class_buttons[cls]
        if cls in self.hidden:
            button.color, button.icon = HIDDEN_CLASS, viser.Icon.EYE_OFF
        else:
            rgb = UNLABELLED_COLOUR if cls < 0 else PALETTE[cls]
            button.color = (int(rgb[0]), int(rgb[1]), int(rgb[2]))
            button.icon = viser.Icon.EYE

    def class_shown(self, cls: int) -> bool:
        """Whether class ``cls`` is drawn (its button shows an open eye)."""
        return cls not in self.hidden

    def _panel_toggle(self, panel: Panel) -> Callable[[Any], None]:
        def toggle(event: Any) -> None:
            if self._quiet:
                return
            self._wanted[panel] = bool(event.target.value)
            self.redraw()
            self.sync_address()

        return toggle

    def _layout_changed(self) -> None:
        if self._quiet:
            return
        self.single.visible = self.layout.value == SINGLE
        self.redraw()
        self.sync_address()

    # ------------------------------------------------------------------ scene
    def visible_panels(self) -> tuple[Panel, ...]:
        """The panels shown, left to right."""
        if self.data is None:
            return ()
        if self.layout.value == SINGLE:
            chosen = [p for p in self.data.panels if p.title == self.single.value]
            return tuple(chosen[:1] or self.data.panels[2:3])
        return tuple(p for p in self.data.panels if p not in OPTIONAL or self.panel_boxes[p].value)

    def redraw(self, *, camera: bool = False) -> None:
        """Lay out the visible panels (sending any not sent yet), then apply visibility; re-fit
        the camera when the number of panels changed (or when asked)."""
        with self._lock:
            data = self.data
            if data is None:
                return
            panels = self.visible_panels()
            offsets = panel_offsets(data.extent, len(panels))
            with self.client.atomic():
                for panel, offset in zip(panels, offsets, strict=True):
                    if panel.key not in self.frames:
                        self._send_panel(panel, data)
                    self.frames[panel.key].position = offset
                    if panel.key == "fused" and self.boxes is None:
                        self._send_boxes(data)
                for key, frame in self.frames.items():
                    frame.visible = any(p.key == key for p in panels)
                self._apply_visibility()
                if camera or len(panels) != self._count:
                    self._count = len(panels)
                    self._set_camera(data, len(panels))

    def _send_panel(self, panel: Panel, data: SceneData) -> None:
        scene = self.client.scene
        path = f"{self._root_path}/{panel.key}"
        frame = scene.add_frame(path, show_axes=False)
        self.frames[panel.key] = frame
        scene.add_label(
            f"{path}/title",
            panel.title,
            position=title_position(data.extent),
            anchor="bottom-center",
            font_screen_scale=1.4,
        )
        rows = slice(None) if self.shown is None else self.shown
        xyz, colours = data.xyz[rows], data.colours_of(panel)[rows]
        size = self._size(data)
        for (cls, changed), index in self._groups[LABEL_KEY.get(panel.key, "fused")].items():
            self.nodes[(panel.key, cls, changed)] = scene.add_point_cloud(
                f"{path}/{class_title(cls)}_{'changed' if changed else 'kept'}",
                xyz[index],
                colours[index],
                point_size=size,
                point_shape="square",
                point_shading="flat",
                precision="float32",
                visible=self._node_visible(cls, changed),
            )

    def _send_boxes(self, data: SceneData) -> None:
        """The objects' boxes, drawn once in the fused panel (the report's objects), a node
        per class so that they follow the class buttons."""
        self.boxes = {
            cls: self.client.scene.add_line_segments(
                f"{self._root_path}/fused/objects_{class_title(cls)}",
                segments,
                colours,
                thickness=2.0,
                thickness_units="screen",
                visible=self._box_visible(cls),
            )
            for cls, (segments, colours) in box_segments(data).items()
        }

    def _box_visible(self, cls: int) -> bool:
        """Boxes are drawn when *Object boxes* is ticked and their class is shown."""
        return bool(self.boxes_box.value) and cls not in self.hidden

    def _show_boxes(self) -> None:
        with self._lock, self.client.atomic():
            for cls, node in (self.boxes or {}).items():
                node.visible = self._box_visible(cls)

    def _size(self, data: SceneData) -> float:
        return float(self.point_size.value) * max(data.spacing, 1e-4)

    def _node_visible(self, cls: int, changed: bool) -> bool:
        return cls not in self.hidden and (changed or not self.only_changed.value)

    def _apply_visibility(self) -> None:
        with self._lock, self.client.atomic():
            for (_, cls, changed), node in self.nodes.items():
                node.visible = self._node_visible(cls, changed)
            self._show_boxes()
            self._status_line()

    def _resize_points(self) -> None:
        with self._lock:
            if self.data is None:
                return
            size = self._size(self.data)
            with self.client.atomic():
                for node in self.nodes.values():
                    node.point_size = size

    def _rebudget(self) -> None:
        """Send the job again within the new point budget, keeping the camera."""
        job_id, camera = self.job_id, self.client.camera
        if job_id is None:
            return
        try:
            pose = (*camera.position, *camera.look_at)
        except (AssertionError, AttributeError):
            pose = None
        auto = self._camera_auto
        self.show_job(job_id, camera=None if auto else pose)

    # ----------------------------------------------------------------- camera
    def _hook_camera(self) -> None:
        if not self._camera_hooked:
            self._camera_hooked = True
            self.client.camera.on_update(lambda _: self._camera_moved())

    def _place_camera(self, position: Any, look_at: Any) -> None:
        """Put the camera where a link or a preset says; the overview no longer follows."""
        self._hook_camera()
        camera = self.client.camera
        camera.up_direction = (0.0, 0.0, 1.0)
        camera.position = np.asarray(position, dtype=np.float64)[:3]
        camera.look_at = np.asarray(look_at, dtype=np.float64)[:3]
        self._camera_auto = False

    def set_view(self, name: str) -> None:
        """A preset view of the whole row: "Fit all" (the overview), "Top", "Front", "Side"."""
        with self._lock:
            data = self.data
            if data is None:
                return
            if name == "Fit all":
                self._set_camera(data, len(self.visible_panels()))
            else:
                aspect = self._aspect()
                pose = view_camera(data.extent, len(self.visible_panels()), name, aspect=aspect)
                self.client.camera.fov = pose.fov
                self._place_camera(pose.position, pose.look_at)
        self.sync_address()

    def _aspect(self) -> float:
        try:
            return float(self.client.camera.aspect)
        except (AssertionError, ZeroDivisionError):
            return 16 / 9

    def _set_camera(self, data: SceneData, count: int) -> None:
        """Point the camera at the whole row; re-fit later if the canvas changes shape."""
        self._hook_camera()
        camera = self.client.camera
        self._count = max(count, 1)
        try:
            aspect = camera.aspect
        except (AssertionError, ZeroDivisionError):
            self._camera_pose = None  # no camera report from the browser yet: place it then
            self._camera_auto = True
            return
        pose = overview_camera(data.extent, self._count, aspect=aspect)
        camera.up_direction = pose.up
        camera.fov = pose.fov
        camera.position = pose.position
        camera.look_at = pose.look_at
        self._camera_pose, self._camera_aspect, self._camera_auto = pose, aspect, True
        self._camera_echoed, self._camera_sent = False, time.monotonic()

    def _camera_moved(self) -> None:
        """Camera reports: keep the overview fitted to the canvas until the user moves it.

        Reports sent before the browser applied our pose still carry the old one, so the user
        is taken to have moved the camera only once our pose has come back and then changed.
        """
        with self._lock:
            data, camera = self.data, self.client.camera
            if data is None:
                return
            if not self._camera_auto:
                self._address_soon()
                return
            pose = self._camera_pose
            if pose is not None:
                ours = np.allclose(camera.position, pose.position, rtol=1e-3, atol=1e-3)
                if self._camera_echoed and not ours:
                    self._camera_auto = False  # the user took over
                    self._address_soon()
                    return
                if not self._camera_echoed:
                    self._camera_echoed = ours
                    if not ours and time.monotonic() - self._camera_sent > ECHO_WAIT_S:
                        self._camera_auto = False
                        return
                if abs(camera.aspect - self._camera_aspect) < 0.01 * self._camera_aspect:
                    return
            self._set_camera(data, self._count)

    # ---------------------------------------------------------------- address
    def view_state(self) -> ViewState:
        """The view as a link would restore it."""
        camera = None
        if not self._camera_auto and self.data is not None:
            try:
                camera = (*self.client.camera.position, *self.client.camera.look_at)
            except AssertionError:
                camera = None
        single = None
        if self.layout.value == SINGLE and self.data is not None:
            single = next((p.key for p in self.data.panels if p.title == self.single.value), None)
        return ViewState(
            job_id=self.job_id,
            camera=None if camera is None else tuple(float(v) for v in camera),
            hidden=frozenset(self.hidden),
            panels=frozenset(p.key for p, want in self._wanted.items() if want),
            only_changed=bool(self.only_changed.value),
            boxes=bool(self.boxes_box.value),
            point_size=float(self.point_size.value),
            single=single,
            budget=None if self.budget.value >= self.cache.max_points else int(self.budget.value),
        )

    def sync_address(self) -> None:
        """Write the current view into the browser's address bar."""
        with self._lock:
            if self._address_due is not None:
                self._address_due.cancel()
                self._address_due = None
            self._address_last = time.monotonic()
            self._address_serial += 1
            path = state_path(self.view_state())
            self.address.content = address_html(path, self._address_serial)

    def _address_soon(self) -> None:
        """The camera moves: update the address at most every :data:`ADDRESS_EVERY_S`."""
        if self._address_due is not None:
            return
        wait = max(0.0, ADDRESS_EVERY_S - (time.monotonic() - self._address_last))
        self._address_due = threading.Timer(wait, self.sync_address)
        self._address_due.daemon = True
        self._address_due.start()

    # ------------------------------------------------------------ click tools
    def _mode_changed(self) -> None:
        self._clear_marks()
        self.tools.mode = str(self.mode.value)
        self.answer.content = {
            MODES[0]: "Click a point in any panel.",
            MODES[1]: "Click two points.",
            MODES[2]: "Click the corners of a planar area, in order.",
        }[self.tools.mode]

    def _clear_marks(self) -> None:
        with self._lock:
            self.tools.clear()

    def _clicked(self, event: Any) -> None:
        """A click in the scene: find the point under it and hand it to the click tools."""
        with self._lock:
            data = self.data
            if data is None:
                return
            origin = np.asarray(event.ray_origin, dtype=np.float64)
            direction = np.asarray(event.ray_direction, dtype=np.float64)
            hit = self.pick(origin, direction)
            if hit is None:
                self.answer.content = "No point under the click."
                return
            marker = 1.5 * self._size(data)
            self.answer.content = self.tools.add(data, hit, marker)

    def pick(self, origin: np.ndarray, direction: np.ndarray) -> Picked | None:
        """The drawn point a ray (world coordinates) hits first, over every visible panel."""
        data = self.data
        if data is None:
            return None
        tolerance = self._pick_tolerance(data, origin)
        best: tuple[float, Picked] | None = None
        for panel in self.visible_panels():
            frame = self.frames.get(panel.key)
            if frame is None:
                continue
            groups = self._groups.get(LABEL_KEY.get(panel.key, "fused"), {})
            drawn = [idx for (cls, ch), idx in groups.items() if self._node_visible(cls, ch)]
            if not drawn:
                continue
            rows = self._rows(np.concatenate(drawn))
            local_origin = origin - np.asarray(frame.position, dtype=np.float64)
            found = pick(data.xyz[rows], local_origin, direction, tolerance)
            if found is None:
                continue
            row = int(rows[found])
            depth = float((data.xyz[row] - local_origin) @ direction)
            if best is None or depth < best[0]:
                best = (depth, Picked(panel.key, row, data.xyz[row].astype(np.float64)))
        return None if best is None else best[1]

    def _pick_tolerance(self, data: SceneData, origin: np.ndarray) -> float:
        """A hit within a drawn point's size, or four pixels at the camera's focus distance."""
        size = self._size(data)
        try:
            camera = self.client.camera
            focus = float(np.linalg.norm(np.asarray(camera.look_at) - origin))
            pixel = 2.0 * focus * np.tan(camera.fov / 2.0) / max(camera.image_height, 1)
        except (AssertionError, AttributeError, ZeroDivisionError):
            pixel = 0.0
        return max(0.75 * size, 4.0 * pixel)

    # -------------------------------------------------------------- downloads
    def send_screenshot(self) -> None:
        """The canvas as the browser renders it now, as a PNG download."""
        import imageio.v3 as iio

        job_id = self.job_id
        camera = self.client.camera
        try:
            height, width = int(camera.image_height), int(camera.image_width)
        except (AssertionError, AttributeError):
            height, width = 900, 1600
        height, width = max(min(height, 2160), 16), max(min(width, 3840), 16)
        try:
            rgba = self.client.get_render(height, width, transport_format="png", timeout=30.0)
        except (TimeoutError, RuntimeError) as exc:
            self.client.add_notification("Screenshot failed", str(exc), color="red")
            return
        image = rgba[..., :3].astype(np.float64)
        if rgba.shape[-1] == 4:  # the background renders transparent: lay it on ours
            alpha = rgba[..., 3:4].astype(np.float64) / 255.0
            image = image * alpha + np.array(BACKGROUND, np.float64) * (1.0 - alpha)
        buffer = io.BytesIO()
        iio.imwrite(buffer, np.round(image).astype(np.uint8), extension=".png")
        entry = self._entries.get(job_id or "")
        stem = Path(entry.filename).stem if entry is not None else (job_id or "view")
        self.client.send_file_download(f"{stem}_view.png", buffer.getvalue(), save_immediately=True)

    def _download_click(self, kinds: tuple[Download, ...]) -> Callable[[Any], None]:
        by_label = {LABELS[k]: k for k in kinds}

        def clicked(event: Any) -> None:
            kind = by_label.get(str(event.target.value))
            if kind is not None:
                self.send_download(kind)

        return clicked

    def send_download(self, kind: Download) -> None:
        """One of the shown job's downloads, sent over this tab's websocket (the tab holds no
        key to fetch the API's address: :mod:`web.downloads`)."""
        job_id = self.job_id
        if job_id is None:
            return
        entry = self._entries.get(job_id)
        name = file_name(None if entry is None else entry.filename, job_id, kind)
        busy = self.client.add_notification(
            f"Preparing {name}", "", loading=True, with_close_button=False
        )
        try:
            body = download_body(self.source, job_id, kind)
        except JointsegError as exc:
            log.warning("job %s: no %s download: %s", job_id, kind, exc)
            message = without_server_paths(str(exc))
            self.client.add_notification("Cannot download", message, color="red")
            return
        except (OSError, ValueError):  # the message would name a path: say what, not where
            log.warning("job %s: its %s download could not be read", job_id, kind)
            self.client.add_notification("Cannot download", f"{job_id}: unreadable", color="red")
            return
        finally:
            busy.remove()
        self.client.send_file_download(name, body, save_immediately=True)
