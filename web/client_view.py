"""What one browser tab sees: its job's panels in the scene and the controls beside them.

Each connected client has its own :class:`ClientView`, built from ``client.scene`` and
``client.gui``, so several people inspect different jobs at once. A job's points are sent once
per panel, split into one node per (class, changed by fusion) group: hiding a class, showing only
the changed points or resizing points are property updates, not new uploads. Switching jobs
removes the old nodes first, so neither the server nor the browser grows with the jobs viewed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import viser

from jointseg.classes import NUM_CLASSES, UNLABELLED
from jointseg.exceptions import JointsegError
from web.layout import CameraPose, overview_camera, panel_offsets, title_position
from web.legend import class_title, iou_html, legend_html, present_classes
from web.memory import release_soon
from web.scene import NETWORK, SEGMENTS, TRUTH, Panel, SceneCache, SceneData, group_points
from web.sources import JobEntry, JobSource

log = logging.getLogger(__name__)

ROOT = "/jointseg"
PLACEHOLDER: str = "(choose a finished job)"
#: Classes hidden when a viewer opens: from above, the ceiling covers the room.
HIDDEN_BY_DEFAULT = frozenset({0})
#: Default point size as a multiple of the shown points' spacing.
POINT_SIZE = 2.0
#: Seconds the browser has to report back a camera pose the viewer set.
ECHO_WAIT_S = 3.0


class ClientView:
    """The per-client state and controls of the viewer.

    Parameters
    ----------
    client : viser.ClientHandle
    source : JobSource
        Finished jobs and their files.
    cache : SceneCache
        Loaded results shared by every client of one viewer (bounded).
    """

    def __init__(self, client: viser.ClientHandle, source: JobSource, cache: SceneCache) -> None:
        self.client = client
        self.source = source
        self.cache = cache
        self.job_id: str | None = None
        self.data: SceneData | None = None
        self.hidden = set(HIDDEN_BY_DEFAULT)
        self.frames: dict[str, viser.FrameHandle] = {}
        self.nodes: dict[tuple[str, int, bool], viser.PointCloudHandle] = {}
        self._groups: dict[str, dict[tuple[int, bool], np.ndarray]] = {}
        self._root: viser.FrameHandle | None = None
        self._labels: dict[str, str] = {}
        self._entries: dict[str, JobEntry] = {}
        self._lock = threading.RLock()
        self._camera_hooked = False
        self._camera_auto = False
        self._camera_pose: CameraPose | None = None
        self._camera_aspect = 0.0
        self._camera_count = 1
        self._camera_echoed = False
        self._camera_sent = 0.0
        self._build_gui()

    # ----------------------------------------------------------------- controls
    def _build_gui(self) -> None:
        gui = self.client.gui
        with gui.add_folder("Job"):
            options: tuple[str, ...] = (PLACEHOLDER,)
            self.picker: viser.GuiDropdownHandle[str] = gui.add_dropdown("Job", options)
            self.refresh = gui.add_button("Refresh list", icon=viser.Icon.REFRESH)
            self.status = gui.add_markdown("No job shown.")
        with gui.add_folder("Display"):
            self.truth_box = gui.add_checkbox("Ground truth panel", True, disabled=True)
            self.segments_box = gui.add_checkbox("Segments panel", False)
            self.point_size = gui.add_slider(
                "Point size", 0.25, 8.0, 0.25, POINT_SIZE, hint="multiple of the point spacing"
            )
            self.only_changed = gui.add_checkbox(
                "Only points changed by fusion", False, hint="labels the fusion replaced"
            )
        # built once and updated per job (no GUI elements are created or removed per job)
        with gui.add_folder("Classes"):
            self.legend = gui.add_html("")
            self.class_boxes = {
                cls: gui.add_checkbox(class_title(cls), cls not in self.hidden, visible=False)
                for cls in (*range(NUM_CLASSES), UNLABELLED)
            }
        with gui.add_folder("Scores (IoU)", visible=False) as self.scores_folder:
            self.scores = gui.add_html("")
        with gui.add_folder("Downloads"):
            self.download_result = gui.add_button("Result", icon=viser.Icon.DOWNLOAD, disabled=True)
            self.download_report = gui.add_button("Report", icon=viser.Icon.DOWNLOAD, disabled=True)

        self.picker.on_update(lambda _: self._picked())
        self.refresh.on_click(lambda _: self.refresh_jobs())
        self.truth_box.on_update(lambda _: self.redraw())
        self.segments_box.on_update(lambda _: self.redraw())
        self.point_size.on_update(lambda _: self._resize_points())
        self.only_changed.on_update(lambda _: self._apply_visibility())
        for cls, box in self.class_boxes.items():
            box.on_update(self._class_toggle(cls))
        self.download_result.on_click(lambda _: self._send_download(result=True))
        self.download_report.on_click(lambda _: self._send_download(result=False))
        self.refresh_jobs()

    def refresh_jobs(self) -> None:
        """Reload the job picker's list (finished jobs, newest first); keep the current choice."""
        try:
            jobs = list(self.source.finished_jobs())
        except Exception:  # the list is best effort: a database hiccup must not kill the tab
            log.exception("listing finished jobs failed")
            jobs = []
        self._labels = {job.label: job.id for job in jobs}
        self._entries = {job.id: job for job in jobs}
        current = self.picker.value
        self.picker.options = (PLACEHOLDER, *self._labels)
        if current in self._labels:
            self._set_picker(current)

    def _set_picker(self, label: str) -> None:
        # viser declares a method between ``value``'s getter and setter, so mypy sees no setter
        self.picker.value = label  # type: ignore[misc]

    def _picked(self) -> None:
        job_id = self._labels.get(self.picker.value)
        if job_id is not None and job_id != self.job_id:
            self.show_job(job_id)

    def select(self, job_id: str) -> None:
        """Show ``job_id`` and select it in the picker (used for links to one job)."""
        label = next((lab for lab, i in self._labels.items() if i == job_id), None)
        if label is None:
            self.refresh_jobs()
            label = next((lab for lab, i in self._labels.items() if i == job_id), None)
        if label is None:
            self.show_job(job_id)
        else:
            self._set_picker(label)  # the picker's callback shows it

    # -------------------------------------------------------------------- jobs
    def show_job(self, job_id: str) -> bool:
        """Replace the scene with ``job_id``'s panels.

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
            self._groups = {
                "network": group_points(data.network, data.changed),
                "fused": group_points(data.fused, data.changed),
            }
            if data.truth is not None:
                self._groups["truth"] = group_points(data.truth, data.changed)
            with self.client.atomic():
                self._root = self.client.scene.add_frame(ROOT, show_axes=False)
                self._update_job_gui(data)
                self.redraw(camera=True)
            self.client.flush()
            release_soon()  # the previous job's clouds and the reading's buffers are freed
            log.info(
                "client %d shows %s: loaded in %.2f s, sent in %.2f s",
                self.client.client_id,
                job_id,
                loaded - started,
                time.perf_counter() - loaded,
            )
            return True

    def clear(self) -> None:
        """Remove the shown job's nodes and job-specific controls."""
        with self._lock:
            if self._root is not None:
                self._root.remove()  # removes every panel node below it
            self._root, self.job_id, self.data = None, None, None
            self.frames, self.nodes, self._groups = {}, {}, {}
            self.download_result.disabled = self.download_report.disabled = True
            self.scores_folder.visible = False
            self.legend.content = ""
            for box in self.class_boxes.values():
                box.visible = False
            self.status.content = "No job shown."

    def _update_job_gui(self, data: SceneData) -> None:
        self.legend.content = legend_html(data.counts)
        present = present_classes(data.counts)
        for cls, box in self.class_boxes.items():
            box.visible = cls in present
        table = iou_html(data.report)
        self.scores.content = table or ""
        self.scores_folder.visible = table is not None
        self.truth_box.disabled = data.truth is None
        self.download_result.disabled = False
        self.download_report.disabled = self.source.report_path(self.job_id or "") is None
        shown = data.xyz.shape[0]
        note = "" if data.voxel is None else f" (voxel {data.voxel * 100:.1f} cm)"
        entry = self._entries.get(self.job_id or "")
        name = f"{entry.filename} [{entry.id[:8]}]" if entry is not None else self.job_id
        self.status.content = f"**{name}**: {shown:,} of {data.total_points:,} points shown{note}."

    def _class_toggle(self, cls: int) -> Callable[[Any], None]:
        def toggle(event: Any) -> None:
            if event.target.value:
                self.hidden.discard(cls)
            else:
                self.hidden.add(cls)
            self._apply_visibility()

        return toggle

    # ------------------------------------------------------------------ scene
    def visible_panels(self) -> tuple[Panel, ...]:
        """The panels shown, left to right."""
        if self.data is None:
            return ()
        chosen = []
        for panel in self.data.panels:
            if panel is TRUTH and not self.truth_box.value:
                continue
            if panel is SEGMENTS and not self.segments_box.value:
                continue
            chosen.append(panel)
        return tuple(chosen)

    def redraw(self, *, camera: bool = False) -> None:
        """Lay out the visible panels (sending any not sent yet), then apply visibility."""
        with self._lock:
            data = self.data
            if data is None:
                return
            panels = self.visible_panels()
            offsets = panel_offsets(data.extent, len(panels))
            for panel, offset in zip(panels, offsets, strict=True):
                if panel.key not in self.frames:
                    self._send_panel(panel, data)
                self.frames[panel.key].position = offset
            for key, frame in self.frames.items():
                frame.visible = any(p.key == key for p in panels)
            self._apply_visibility()
            if camera:
                self._set_camera(data, len(panels))

    def _send_panel(self, panel: Panel, data: SceneData) -> None:
        scene = self.client.scene
        frame = scene.add_frame(f"{ROOT}/{panel.key}", show_axes=False)
        self.frames[panel.key] = frame
        scene.add_label(
            f"{ROOT}/{panel.key}/title",
            panel.title,
            position=title_position(data.extent),
            anchor="bottom-center",
            font_screen_scale=1.4,
        )
        colours = data.colours_of(panel)
        key = panel.key if panel in (NETWORK, TRUTH) else "fused"
        size = self._size(data)
        for (cls, changed), index in self._groups[key].items():
            self.nodes[(panel.key, cls, changed)] = scene.add_point_cloud(
                f"{ROOT}/{panel.key}/{class_title(cls)}_{'changed' if changed else 'kept'}",
                data.xyz[index],
                colours[index],
                point_size=size,
                point_shape="square",
                point_shading="flat",
                precision="float32",
                visible=self._node_visible(cls, changed),
            )

    def _size(self, data: SceneData) -> float:
        return float(self.point_size.value) * max(data.spacing, 1e-4)

    def _node_visible(self, cls: int, changed: bool) -> bool:
        return cls not in self.hidden and (changed or not self.only_changed.value)

    def _apply_visibility(self) -> None:
        with self._lock, self.client.atomic():
            for (_, cls, changed), node in self.nodes.items():
                node.visible = self._node_visible(cls, changed)

    def _resize_points(self) -> None:
        with self._lock:
            if self.data is None:
                return
            size = self._size(self.data)
            with self.client.atomic():
                for node in self.nodes.values():
                    node.point_size = size

    def _set_camera(self, data: SceneData, count: int) -> None:
        """Point the camera at the whole row; re-fit later if the canvas changes shape."""
        camera = self.client.camera
        if not self._camera_hooked:
            self._camera_hooked = True
            camera.on_update(lambda _: self._camera_moved())
        self._camera_count = max(count, 1)
        try:
            aspect = camera.aspect
        except (AssertionError, ZeroDivisionError):
            self._camera_pose = None  # no camera report from the browser yet: place it then
            self._camera_auto = True
            return
        pose = overview_camera(data.extent, self._camera_count, aspect=aspect)
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
            if data is None or not self._camera_auto:
                return
            pose = self._camera_pose
            if pose is not None:
                ours = np.allclose(camera.position, pose.position, rtol=1e-3, atol=1e-3)
                if self._camera_echoed and not ours:
                    self._camera_auto = False  # the user took over
                    return
                if not self._camera_echoed:
                    self._camera_echoed = ours
                    if not ours and time.monotonic() - self._camera_sent > ECHO_WAIT_S:
                        self._camera_auto = False
                        return
                if abs(camera.aspect - self._camera_aspect) < 0.01 * self._camera_aspect:
                    return
            self._set_camera(data, self._camera_count)

    # -------------------------------------------------------------- downloads
    def _send_download(self, *, result: bool) -> None:
        job_id = self.job_id
        if job_id is None:
            return
        path: Path | None = (
            self.source.result_path(job_id) if result else self.source.report_path(job_id)
        )
        if path is None or not path.is_file():
            self.client.add_notification("Nothing to download", f"{job_id} has no such file")
            return
        entry = self._entries.get(job_id)
        stem = Path(entry.filename).stem if entry is not None else job_id
        name = f"{stem}_segmented{path.suffix}" if result else f"{stem}_report.json"
        self.client.send_file_download(name, path.read_bytes(), save_immediately=True)
