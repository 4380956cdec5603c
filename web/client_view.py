"""What one browser tab sees: its job's panels in the scene and the controls beside them.

Each connected client has its own :class:`ClientView`, built from ``client.scene`` and
``client.gui``, so several people inspect different jobs at once. The view wires together small
parts that each own one concern, as viser's own handles do:

- :class:`web.controls.Controls`: the control panel's folders and controls;
- :class:`web.job_list.JobList`: the job picker and the jobs it lists;
- :class:`web.panels.PanelScene`: the shown job's nodes in the scene, and what a click hits;
- :class:`web.camera.CameraFollow`: the camera, fitted until the user moves it;
- :class:`web.address.AddressBar`: the browser's address following the view
  (:mod:`web.view_state`): a copied link opens the same job with the same camera, classes and
  toggles, and carries no key (whoever opens it signs in).

Switching jobs removes the old nodes first, so neither the server nor the browser grows with the
jobs viewed.
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

from jointseg.exceptions import JointsegError
from server.api.results import Download
from web.address import AddressBar
from web.camera import CameraFollow
from web.controls import CLICK_HINTS, OPTIONAL, SINGLE, Controls
from web.downloads import send_download
from web.job_list import JobList
from web.layout import overview_camera, panel_offsets, view_camera
from web.memory import release_soon
from web.panels import PanelScene
from web.scene import Panel, SceneCache, SceneData
from web.screenshot import BACKGROUND, send_screenshot
from web.sources import JobEntry, JobSource
from web.tools import ClickTools, Picked
from web.view_state import ViewState

log = logging.getLogger(__name__)

#: Classes hidden when a viewer opens: from above, the ceiling covers the room.
HIDDEN_BY_DEFAULT = frozenset({0})


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
        self.job_id: str | None = None
        self.hidden = set(HIDDEN_BY_DEFAULT if self.asked.hidden is None else self.asked.hidden)
        self._lock = threading.RLock()
        self._count = 0  # panels the camera was last fitted to
        client.scene.set_background_image(
            np.broadcast_to(np.array(BACKGROUND, np.uint8), (4, 4, 3)).copy(), format="png"
        )
        self.ui = Controls(client.gui, self.asked, cache.max_points, sign_out)
        self._wanted = {panel: self.ui.panel_boxes[panel].value for panel in OPTIONAL}
        self.jobs = JobList(self.ui.picker, source)
        self.panels = PanelScene(client.scene, self.hidden)
        self._read_toggles()
        self.camera = CameraFollow(client.camera, self._lock, on_user_move=self._camera_moved)
        self.address = AddressBar(self.ui.address, self.view_state, self._lock)
        self.tools = ClickTools(client.scene, self.panels.root_path)
        for cls in self.ui.class_buttons:
            self.ui.paint_class(cls, cls in self.hidden)
        self._wire()
        self.refresh_jobs()
        client.scene.on_click()(self._clicked)

    # the shown job's scene, as the tests and benchmarks read it
    @property
    def data(self) -> SceneData | None:
        """The shown job's scene data (None: no job shown)."""
        return self.panels.data

    def close(self) -> None:
        """The tab closed: drop its reference to the points at once (viser frees its nodes)."""
        self.panels.data = None

    # ----------------------------------------------------------------- controls
    def _wire(self) -> None:
        ui = self.ui
        ui.picker.on_update(lambda _: self._picked())
        ui.refresh.on_click(lambda _: self.refresh_jobs())
        ui.layout.on_update(lambda _: self._changed(self._layout_changed))
        ui.single.on_update(lambda _: self._changed(self.redraw))
        for panel, box in ui.panel_boxes.items():
            box.on_update(self._panel_toggle(panel))
        ui.point_size.on_update(lambda _: self._changed(self._resize_points))
        ui.only_changed.on_update(lambda _: self._changed(self._apply_visibility))
        ui.boxes.on_update(lambda _: self._changed(self._apply_visibility))
        ui.budget.on_update(lambda _: self._changed(self._rebudget))
        ui.views.on_click(lambda event: self.set_view(str(event.target.value)))
        ui.screenshot.on_click(lambda _: self.send_screenshot())
        ui.mode.on_update(lambda _: self._mode_changed())
        ui.clear_marks.on_click(lambda _: self._clear_marks())
        for cls, button in ui.class_buttons.items():
            button.on_click(self._class_toggle(cls))
        ui.on_download(self.send_download)

    def _changed(self, action: Callable[[], None]) -> None:
        """A control the user changed: act, then write the view into the address."""
        if self.ui.quiet:
            return
        action()
        self.address.sync()

    def _read_toggles(self) -> None:
        """The panels' drawing options from the controls."""
        self.panels.only_changed = bool(self.ui.only_changed.value)
        self.panels.boxes_on = bool(self.ui.boxes.value)
        self.panels.size_factor = float(self.ui.point_size.value)

    def _apply_visibility(self) -> None:
        """Classes, *only changed* or *Object boxes* changed: properties, no new upload."""
        with self._lock, self.client.atomic():
            self._read_toggles()
            self.panels.apply_visibility()
            self._status_line()

    def _resize_points(self) -> None:
        with self._lock, self.client.atomic():
            self._read_toggles()
            self.panels.resize()

    def refresh_jobs(self) -> None:
        """Reload the job picker's list; then, if the shown job has gone (deleted, or no longer
        this key's), say so."""
        with self._lock:
            with self.ui.quietly():
                known = self.jobs.refresh()
            job_id = self.job_id
            if known is not None and job_id is not None and job_id not in self.jobs.entries:
                self._check_shown(job_id, known.get(job_id))

    def _check_shown(self, job_id: str, entry: JobEntry | None) -> None:
        """The shown job is not in the list: beyond the list's length, or gone. When gone, its
        panels are removed and the tab says so, rather than showing a job that is no more."""
        if not self.jobs.gone(job_id):
            return  # still there (the list holds the newest jobs only)
        name = f"{entry.filename} [{job_id[:8]}]" if entry is not None else job_id
        self.clear()
        self.ui.status.content = (
            f"**{name} was deleted** (or this key may no longer see it): nothing of it is "
            "shown. Choose another job."
        )
        self.client.add_notification(
            "Job deleted", f"{name} is no longer on the service.", color="red"
        )
        self.address.sync()

    def _picked(self) -> None:
        if self.ui.quiet:
            return
        job_id = self.jobs.job_of(self.ui.picker.value)
        if job_id is not None and job_id != self.job_id:
            self.show_job(job_id)

    def select(self, job_id: str) -> None:
        """Show ``job_id`` and select it in the picker (used for links to one job)."""
        if self.jobs.label_of(job_id) is None:
            self.refresh_jobs()
        label = self.jobs.label_of(job_id)
        if label is not None:
            self.ui.set_quietly(self.ui.picker, label)
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
            self.job_id = job_id
            with self.client.atomic():
                self.tools.root = self.panels.start(data, int(self.ui.budget.value))
                report = self.source.report_path(job_id) is not None
                self.ui.show_job(data, report=report, wanted=self._wanted, single=self.asked.single)
                self.camera.active = True
                self.redraw(camera=camera is None)
                if camera is not None:
                    self.camera.place(camera[:3], camera[3:])
            self.client.flush()
            self.address.sync()
            release_soon()  # the previous job's clouds and the reading's buffers are freed
            log.info(
                "client %d shows %s: loaded in %.2f s, sent in %.2f s",
                self.client.client_id, job_id, loaded - started, time.perf_counter() - loaded,
            )  # fmt: skip
            return True

    def clear(self) -> None:
        """Remove the shown job's nodes and job-specific controls."""
        with self._lock:
            self.panels.clear()
            self.tools.forget()
            self.camera.active = False
            self.job_id = None
            self.ui.clear()

    def _status_line(self) -> None:
        """How many points the browser draws now, of how many the scan has."""
        if self.data is not None:
            name = self.jobs.name(self.job_id or "")
            self.ui.status.content = self.panels.status(name, self.visible_panels())

    def _class_toggle(self, cls: int) -> Callable[[Any], None]:
        def toggle(_: Any) -> None:
            with self._lock:
                self.hidden.symmetric_difference_update({cls})
                self.ui.paint_class(cls, cls in self.hidden)
                self._apply_visibility()
            self.address.sync()

        return toggle

    def class_shown(self, cls: int) -> bool:
        """Whether class ``cls`` is drawn (its button shows an open eye)."""
        return cls not in self.hidden

    def _panel_toggle(self, panel: Panel) -> Callable[[Any], None]:
        def toggle(event: Any) -> None:
            if self.ui.quiet:
                return
            self._wanted[panel] = bool(event.target.value)
            self.redraw()
            self.address.sync()

        return toggle

    def _layout_changed(self) -> None:
        self.ui.single.visible = self.ui.layout.value == SINGLE
        self.redraw()

    # ------------------------------------------------------------------ scene
    def visible_panels(self) -> tuple[Panel, ...]:
        """The panels shown, left to right."""
        data = self.data
        return () if data is None else self.ui.visible_panels(data)

    def redraw(self, *, camera: bool = False) -> None:
        """Lay out the visible panels (sending any not sent yet), then apply visibility; re-fit
        the camera when the number of panels changed (or when asked)."""
        with self._lock:
            data = self.data
            if data is None:
                return
            panels = self.visible_panels()
            with self.client.atomic():
                self.panels.lay_out(panels, panel_offsets(data.extent, len(panels)))
                self._status_line()
                if camera or len(panels) != self._count:
                    self._count = len(panels)
                    self._fit_all(data)

    def _fit_all(self, data: SceneData) -> None:
        count = max(self._count, 1)
        self.camera.follow(lambda aspect: overview_camera(data.extent, count, aspect=aspect))

    def _rebudget(self) -> None:
        """Send the job again within the new point budget, keeping the camera."""
        job_id = self.job_id
        if job_id is not None:
            self.show_job(job_id, camera=None if self.camera.auto else self.camera.pose())

    def set_view(self, name: str) -> None:
        """A preset view of the whole row: "Fit all" (the overview), "Top", "Front", "Side"."""
        with self._lock:
            data = self.data
            if data is None:
                return
            if name == "Fit all":
                self._fit_all(data)
            else:
                count, aspect = len(self.visible_panels()), self.camera.aspect()
                pose = view_camera(data.extent, count, name, aspect=aspect)
                self.camera.place(pose.position, pose.look_at, fov=pose.fov)
        self.address.sync()

    def _camera_moved(self) -> None:
        self.address.soon()

    def view_state(self) -> ViewState:
        """The view as a link would restore it."""
        data = self.data
        camera = None if self.camera.auto or data is None else self.camera.pose()
        ui = self.ui
        return ViewState(
            job_id=self.job_id,
            camera=camera,
            hidden=frozenset(self.hidden),
            panels=frozenset(p.key for p, want in self._wanted.items() if want),
            only_changed=bool(ui.only_changed.value),
            boxes=bool(ui.boxes.value),
            point_size=float(ui.point_size.value),
            single=None if data is None else ui.panel_key(data),
            budget=None if ui.budget.value >= self.cache.max_points else int(ui.budget.value),
        )

    # ------------------------------------------------------------ click tools
    def _mode_changed(self) -> None:
        with self._lock:
            self.tools.clear()
            self.tools.mode = str(self.ui.mode.value)
            self.ui.answer.content = CLICK_HINTS[self.tools.mode]

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
            hit = self.pick(origin, np.asarray(event.ray_direction, dtype=np.float64))
            if hit is None:
                self.ui.answer.content = "No point under the click."
                return
            self.ui.answer.content = self.tools.add(data, hit, 1.5 * self.panels.point_size())

    def pick(self, origin: np.ndarray, direction: np.ndarray) -> Picked | None:
        """The drawn point a ray (world coordinates) hits first, over every visible panel: within
        a drawn point's size, or four pixels at the camera's focus distance."""
        tolerance = max(0.75 * self.panels.point_size(), 4.0 * self.camera.pixel_size(origin))
        return self.panels.pick(origin, direction, self.visible_panels(), tolerance)

    # -------------------------------------------------------------- downloads
    def send_screenshot(self) -> None:
        """The canvas as the browser renders it now, as a PNG download."""
        filename = self.jobs.filename(self.job_id)
        stem = Path(filename).stem if filename else (self.job_id or "view")
        width, height = self.camera.canvas()
        send_screenshot(self.client, stem, width or 1600, height or 900)

    def send_download(self, kind: Download) -> None:
        """One of the shown job's downloads, sent over this tab's websocket (the tab holds no
        key to fetch the API's address: :mod:`web.downloads`)."""
        job_id = self.job_id
        if job_id is not None:
            send_download(self.client, self.source, job_id, kind, self.jobs.filename(job_id))
