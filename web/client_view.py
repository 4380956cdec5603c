"""What one browser tab sees: its job's panels in the scene and the controls beside them.

Each connected client has its own :class:`ClientView`, built from ``client.scene`` and
``client.gui``, so several people inspect different jobs at once. The view wires together small
parts that each own one concern, as viser's own handles do:

- :class:`web.controls.Controls`: the control panel's folders and controls, among them
  :class:`web.clipping.ClipControls` (the clip box and the slice);
- :class:`web.job_list.JobList`: the job picker and the jobs it lists;
- :class:`web.panels.PanelScene`: the shown job's nodes in the scene, and what a click hits;
- :class:`web.camera.CameraFollow`: the camera: the overview fitted until the user moves it,
  the plan and the elevations kept near orthographic;
- :class:`web.address.AddressBar`: the browser's address following the view
  (:mod:`web.view_state`): a copied link opens the same job with the same camera, classes and
  toggles, and carries no key (whoever opens it signs in); a
  :class:`web.address.PageElement` puts the legend and scale bar over the canvas
  (:mod:`web.overlay`).

Switching jobs removes the old nodes first, so neither the server nor the browser grows with the
jobs viewed.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import viser

from jointseg.exceptions import JointsegError
from server.results import Download
from web.address import AddressBar, PageElement
from web.camera import FIT_ALL, CameraFollow
from web.controls import GONE, Controls
from web.downloads import send_download
from web.frame_panel import FramePanel
from web.job_list import JobList
from web.label_editing import LabelEditing
from web.layout import panel_offsets, row_axis
from web.memory import release_soon
from web.object_list import ListedObject, ObjectList
from web.overlay import Overlay, overlay_html, overlay_of
from web.panels import PanelScene
from web.scene import Panel, SceneCache, SceneData
from web.screenshot import BACKGROUND, SIZES, picture, send_screenshot
from web.sources import JobSource
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
        self.ui = Controls(
            client.gui,
            self.asked,
            cache.max_points,
            hidden=self.hidden,
            clip_changed=self._clip_changed,
            sign_out=sign_out,
        )
        self.jobs = JobList(self.ui.picker, source)
        self.panels = PanelScene(client.scene, self.hidden)
        self.panels.restyle(*self.ui.look())
        self.camera = CameraFollow(client.camera, self._lock, on_user_move=self._camera_moved)
        self.camera.view = self.asked.view or FIT_ALL
        self.address = AddressBar(self.ui.address, self.view_state, self._lock)
        self.overlay = PageElement(
            self.ui.overlay, lambda serial: overlay_html(self.overlay_state(), serial), self._lock
        )
        self.tools = ClickTools(client.scene, self.panels.root_path)
        self.objects = ObjectList(client.gui, self.ui.object_list, self.select_object)
        self.editing = LabelEditing(self)  # the Edit labels folder (web.label_editing)
        # the Frame folder (web.frame_panel): re-runs go through the job page, which has the key
        self.frame = FramePanel(client.gui, getattr(source, "job_page_port", None))
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
        ui.layout.on_update(lambda _: self._changed(self.redraw))
        ui.single.on_update(lambda _: self._changed(self.redraw))
        ui.on_panels(lambda: self._changed(self.redraw))
        for handle in (ui.point_size, ui.only_changed, ui.boxes):
            handle.on_update(lambda _: self._changed(self._restyle))
        ui.budget.on_update(lambda _: self._changed(self._resend))
        ui.views.on_click(lambda event: self.set_view(str(event.target.value)))
        ui.screenshot.on_click(lambda _: self.send_screenshot())
        ui.mode.on_update(lambda _: self.tools.set_mode(str(ui.mode.value), ui.answer))
        ui.clear_marks.on_click(lambda _: self._clear_marks())
        ui.on_class(self._toggle_class)
        ui.on_download(self.send_download)

    def _changed(self, action: Callable[[], None]) -> None:
        """A control the user changed: act, then write the view into the address."""
        if self.ui.quiet:
            return
        action()
        self.address.sync()

    def _restyle(self) -> None:
        """Classes, *only changed*, *Object boxes* or the point size changed: node properties,
        no new upload."""
        with self._lock, self.client.atomic():
            self.panels.restyle(*self.ui.look())
            self._status_line()

    def refresh_jobs(self) -> None:
        """Reload the job picker's list; then, if the shown job has gone (deleted, or no longer
        this key's), say so."""
        with self._lock:
            with self.ui.quietly():
                gone = self.jobs.refresh(self.job_id)
            if gone is not None:
                self._job_gone(gone)

    def _job_gone(self, name: str) -> None:
        """The shown job was deleted: its panels go, and the tab says so rather than showing a
        job that is no more."""
        self.clear()
        self.ui.status.content = GONE.format(name=name)
        self.client.add_notification("Job deleted", f"{name} is gone.", color="red")
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
                data = self.jobs.load(job_id, self.cache)
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
                report = self.source.report_path(job_id) is not None
                self.ui.show_job(data, report=report, single=self.asked.single)
                self.objects.show_job(data)
                kept = self.ui.clip.kept(data)
                self.tools.root = self.panels.start(data, int(self.ui.budget.value), kept)
                self.editing.show_job(job_id)
                self.frame.show_job(job_id, data.report)
                self.camera.active = True
                self.redraw(camera=camera is None)
                if camera is not None:  # a link's: a plan's or elevation's has its narrow field
                    self.camera.restore(camera, self.asked.fov)
            self.client.flush()
            self.address.sync()
            self.overlay.sync()
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
            self.objects.clear()
            self.editing.clear()
            self.frame.clear()
            self.overlay.sync()

    def _status_line(self) -> None:
        """How many points the browser draws now, of how many the scan has."""
        if self.data is not None:
            name = self.jobs.name(self.job_id or "")
            self.ui.status.content = self.panels.status(name, self.visible_panels())

    def _toggle_class(self, cls: int) -> None:
        with self._lock:
            self.hidden.symmetric_difference_update({cls})
            self.ui.paint_class(cls, cls in self.hidden)
            self._restyle()
        self.address.sync()
        self.overlay.sync()

    def class_shown(self, cls: int) -> bool:
        """Whether class ``cls`` is drawn (its button shows an open eye)."""
        return cls not in self.hidden

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
            axis = row_axis(self.camera.view)
            with self.client.atomic():
                self.panels.lay_out(
                    panels, panel_offsets(data.extent, len(panels), axis=axis), axis
                )
                self._status_line()
                if camera or len(panels) != self._count:
                    self._count = len(panels)
                    self.camera.show(self.camera.view, data.extent, max(self._count, 1))

    def _clip_changed(self) -> None:
        """The clip box or the slice settled after a change (a timer's thread)."""
        self._resend()
        self.editing.reselect()  # a region selection follows the box and the slice
        self.address.sync()

    def _resend(self) -> None:
        """Send the shown job's panels again (the point budget, the clip box or the slice
        changed), keeping the camera and the controls; marks go with the old nodes."""
        with self._lock:
            data = self.data
            if data is None:
                return
            with self.client.atomic():
                self.tools.forget()
                kept = self.ui.clip.kept(data)
                self.tools.root = self.panels.start(data, int(self.ui.budget.value), kept)
                self.redraw()
            self.client.flush()

    def set_view(self, name: str) -> None:
        """A view of the whole row: "Fit all" (the overview), or the plan ("Top") or an
        elevation ("Front", "Side"), near enough orthographic (:mod:`web.camera`)."""
        with self._lock:
            if self.data is None:
                return
            self.camera.view = name
            self.redraw(camera=True)
        self.address.sync()
        self.overlay.sync()

    def _camera_moved(self) -> None:
        self.address.soon()
        self.overlay.soon()  # the scale bar follows a zoom

    def overlay_state(self, factor: int = 1) -> Overlay:
        """The legend and scale bar over the canvas (and in a screenshot ``factor`` times it)."""
        span = self.camera.span() if self.camera.ortho else None
        return overlay_of(self.data, self.hidden, span, self.camera.canvas()[1])

    def view_state(self) -> ViewState:
        """The view as a link would restore it."""
        camera = self.camera.link_state() if self.data is not None else ViewState()
        return self.ui.view_state(
            camera, self.job_id, self.data, self.hidden, self.cache.max_points
        )

    # ------------------------------------------------------------ click tools
    def select_object(self, obj: ListedObject) -> None:
        """An object of the list: select it in every panel and fly to its copy in the fused
        panel (or the one large panel)."""
        with self._lock:
            panels = self.visible_panels()
            focus = next((p for p in panels if p.key == "fused"), panels[0] if panels else None)
            if focus is None:
                return
            self.panels.select(obj.edges(), panels)
            self.ui.answer.content = obj.description
            target = obj.centre + np.asarray(self.panels.frames[focus.key].position)
        self.camera.fly_to(target, obj.radius)
        self.address.sync()

    def _clear_marks(self) -> None:
        with self._lock:
            self.tools.clear()
            self.panels.select(None, ())

    def _clicked(self, event: Any) -> None:
        """A click in the scene: find the point under it and hand it to the click tools."""
        with self._lock:
            data = self.data
            if data is None:
                return
            origin = np.asarray(event.ray_origin, dtype=np.float64)
            if self.editing.clicked(origin, np.asarray(event.ray_direction, dtype=np.float64)):
                return  # a selection for Edit labels
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
        """The scene as the tab shows it, at the chosen size with the legend, as a PNG."""
        width, height = self.camera.canvas()
        factor, stem = SIZES.get(str(self.ui.shot_size.value), 2), self.jobs.stem(self.job_id)
        send_screenshot(
            self.client, stem, self._picture, (width or 1600, height or 900), factor,
            self.overlay_state,
        )  # fmt: skip

    def _picture(self, size: tuple[int, int], factor: int) -> np.ndarray:
        with self._lock:
            return picture(self.panels, self.tools, self.camera, size, factor)

    def send_download(self, kind: Download) -> None:
        """One of the shown job's downloads, sent over this tab's websocket (the tab holds no
        key to fetch the API's address: :mod:`web.downloads`)."""
        job_id = self.job_id
        if job_id is not None:
            send_download(self.client, self.source, job_id, kind, self.jobs.filename(job_id))
