"""A tab's camera: placed by the viewer, kept fitted to the canvas until the user moves it.

viser reports a browser's camera (its pose and canvas size) before it calls the viewer's
``on_client_connect``, so a view's camera and canvas are known from its first moment; the
browser then reports every change, the user's and the viewer's own, a few times a second.

Three things are read from those reports:

- whether the **user took over**: the overview (*Fit all*) is re-fitted whenever the canvas
  changes shape (the control panel docks, the window is resized) until the user moves the
  camera. Reports sent before the browser applied the viewer's pose still carry the old one, so
  the user is taken to have moved only once the viewer's pose has come back and then changed;
- whether the **plan or an elevation** still holds: the presets stand in for orthographic views
  with a far camera and a narrow field (:func:`web.layout.ortho_camera`). A wheel dollies the
  camera nearer, which would bring the perspective back, so the viewer puts it back at its
  distance with the field narrowed to show the same (a zoom); once the user orbits away (more
  than :data:`ORBIT_DEG`), the camera becomes an ordinary perspective one again, framing the
  same;
- whether the browser **applied a pose**: setting a pose on viser's camera handle changes the
  server's copy at once, so only a report says what the browser draws (a click aimed through a
  pose the browser has not applied yet goes through the old one). viser calls the viewer back
  for a report with its live handle, which a pose set since then has already overwritten, so a
  callback whose handle was last written by the viewer is no report at all: it is skipped (read
  as the browser's, it would be the pose coming back; and the browser's next, older report, the
  user moving away from it).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np
import viser

from web.layout import (
    FAR,
    FOV_DEG,
    NEAR,
    ORTHO_NEAR,
    CameraPose,
    ortho_camera,
    ortho_far,
    overview_camera,
)
from web.render import Eye
from web.view_state import ViewState

#: Canvas width / height assumed while the canvas has no size (a hidden tab).
DEFAULT_ASPECT = 16 / 9
#: Seconds the browser has to report back a pose the viewer set (a tab opening a big job under
#: load can take seconds; a report older than the pose would undo it).
ECHO_WAIT_S = 10.0
#: Relative change of the canvas's aspect that re-fits a following camera.
REFIT_ASPECT = 0.01
#: Degrees the user may turn a plan or an elevation before it becomes a perspective view.
ORBIT_DEG = 1.0
#: Relative change of the camera's distance in a plan or elevation that is taken as a zoom.
ZOOM_SHARE = 0.02
#: Seconds a flight to an object takes, and the poses it is sent in.
FLIGHT_S, FLIGHT_STEPS = 0.5, 10
#: The overview; the other views (keys of :data:`web.layout.VIEW_DIRECTIONS`) are presets.
FIT_ALL = "Fit all"

Vector = Sequence[float] | np.ndarray


class CameraFollow:
    """The camera of one tab: the view chosen, the poses the viewer sets and what the browser
    reports back.

    Parameters
    ----------
    camera : viser.CameraHandle
        The tab's camera (``client.camera``).
    lock : threading.RLock
        The view's lock: a report and a redraw never interleave.
    on_user_move : callable
        Called on a report of a camera the user moves (the view writes it into the address).
    """

    def __init__(
        self,
        camera: viser.CameraHandle,
        lock: threading.RLock,
        *,
        on_user_move: Callable[[], None],
    ) -> None:
        self.camera = camera
        self.active = False  # a job is shown: its reports mean something
        self.view = FIT_ALL  # the view last chosen: the overview or a preset
        self.ortho = False  # the camera stands in for an orthographic view
        self._lock = lock
        self._on_user_move = on_user_move
        self._fit: Callable[[float], CameraPose] | None = None  # set while the camera follows
        self._pose: CameraPose | None = None  # the last pose sent
        self._axis: tuple[np.ndarray, float] | None = None  # a preset's direction, distance
        self._aspect = 0.0  # the canvas's aspect when it was sent
        self._echoed = False  # the browser has reported it back
        self._sent = 0.0
        self._sent_at = 0.0  # time.time() of the last pose sent (viser stamps reports so)
        self._reported: tuple[np.ndarray, np.ndarray] | None = None
        camera.on_update(self._moved)

    @property
    def auto(self) -> bool:
        """Whether the camera follows the canvas (the user has not moved it since it was fitted)."""
        return self._fit is not None

    def canvas(self) -> tuple[int, int]:
        """The canvas's size in pixels, (width, height), as the browser last reported it."""
        return int(self.camera.image_width), int(self.camera.image_height)

    def aspect(self) -> float:
        """Canvas width / height (:data:`DEFAULT_ASPECT` while the canvas has no size)."""
        width, height = self.canvas()
        return width / height if width > 0 and height > 0 else DEFAULT_ASPECT

    def pose(self) -> tuple[float, ...]:
        """Position and look-at, six floats (what a link restores)."""
        return (*map(float, self.camera.position), *map(float, self.camera.look_at))

    def link_state(self) -> ViewState:
        """The camera as a link restores it: its pose (none while it follows the canvas), the
        plan or elevation chosen, and a plan's or elevation's narrow field of view."""
        pose = None if self.auto else self.pose()
        return ViewState(
            camera=pose,
            view=None if self.view == FIT_ALL else self.view,
            fov=float(self.camera.fov) if pose is not None and self.ortho else None,
        )

    def show(self, view: str, extent: np.ndarray, count: int) -> None:
        """Frame a row of ``count`` panels of ``extent``: the overview (:data:`FIT_ALL`, followed
        while the canvas changes shape) or a preset plan or elevation."""
        with self._lock:
            self.view = view
            if view == FIT_ALL:
                self._fit = lambda aspect: overview_camera(extent, count, aspect=aspect)
                self._send(self._fit(self.aspect()))
            else:
                self._fit = None
                self._send(ortho_camera(extent, count, view, aspect=self.aspect()), ortho=True)

    def restore(self, pose: Sequence[float], fov: float | None) -> None:
        """A link's camera: position and look-at (six floats) and, for a plan or an elevation,
        its narrow field of view."""
        self.place(pose[:3], pose[3:6], fov=fov, ortho=fov is not None)

    def place(
        self, position: Vector, look_at: Vector, *, fov: float | None = None, ortho: bool = False
    ) -> None:
        """Put the camera at a pose (a link's); it no longer follows the canvas. ``ortho``: the
        pose is a plan's or an elevation's (far away, narrow), kept so while the user zooms."""
        with self._lock:
            self._fit = None
            pose = CameraPose(
                position=_vector(position),
                look_at=_vector(look_at),
                fov=float(self.camera.fov) if fov is None else fov,
            )
            if ortho:
                distance = float(np.linalg.norm(np.subtract(pose.position, pose.look_at)))
                pose = CameraPose(
                    pose.position,
                    pose.look_at,
                    fov=pose.fov,
                    near=ORTHO_NEAR,
                    far=ortho_far(distance),
                )
            self._send(pose, ortho=ortho)

    def fly_to(self, target: np.ndarray, radius: float) -> None:
        """Move the camera over :data:`FLIGHT_S` to look at ``target`` from where it looks now,
        near enough that a ball of ``radius`` fills about a third of the view; a plan stays a
        plan (its field narrows instead)."""
        with self._lock:
            position = np.asarray(self.camera.position, dtype=np.float64)
            look_at = np.asarray(self.camera.look_at, dtype=np.float64)
            fov, ortho = float(self.camera.fov), self.ortho
            offset = position - look_at
            back = offset / max(float(np.linalg.norm(offset)), 1e-9)
            if ortho and self._axis is not None:
                back, distance = self._axis
                end_fov = 2.0 * math.atan(3.0 * radius / distance)
            else:
                distance, end_fov = 3.0 * radius / math.tan(fov / 2.0), fov
            end = target + back * distance
            self._fit = None
        for step in range(1, FLIGHT_STEPS + 1):
            t = 0.5 - 0.5 * math.cos(math.pi * step / FLIGHT_STEPS)  # eased
            at = look_at + (target - look_at) * t
            pose = CameraPose(
                _vector(position + (end - position) * t),
                _vector(at),
                fov=fov + (end_fov - fov) * t,
                near=ORTHO_NEAR if ortho else NEAR,
                far=ortho_far(distance) if ortho else FAR,
            )
            with self._lock:
                self._send(pose, ortho=ortho)
            time.sleep(FLIGHT_S / FLIGHT_STEPS)

    def reported(self, position: Vector, look_at: Vector, *, atol: float = 1e-3) -> bool:
        """Whether the browser last reported the camera at this pose (it applied it)."""
        seen = self._reported
        return (
            seen is not None
            and np.allclose(seen[0], position, atol=atol)
            and np.allclose(seen[1], look_at, atol=atol)
        )

    def applied(self) -> bool:
        """Whether the browser has reported the last pose the viewer set (it draws it now)."""
        pose = self._pose
        return pose is not None and self.reported(pose.position, pose.look_at)

    def eye(self) -> Eye:
        """The camera to draw a screenshot from: a plan's or elevation's truly orthographic."""
        camera = self.camera
        return Eye(
            position=np.array(camera.position),
            look_at=np.array(camera.look_at),
            fov=float(camera.fov),
            ortho=self.ortho,
        )

    def span(self, at: np.ndarray | None = None) -> float:
        """Metres the canvas's height spans at the look-at point's distance from ``at``
        (default: the camera): the same everywhere in a plan or an elevation."""
        origin = self.camera.position if at is None else at
        focus = float(np.linalg.norm(np.asarray(self.camera.look_at) - origin))
        return 2.0 * focus * math.tan(float(self.camera.fov) / 2.0)

    def pixel_size(self, at: np.ndarray | None = None) -> float:
        """Metres one of the canvas's pixels spans at the look-at point's distance from ``at``."""
        _, height = self.canvas()
        return self.span(at) / height if height > 0 else 0.0

    def _send(self, pose: CameraPose, *, ortho: bool = False) -> None:
        camera = self.camera
        camera.up_direction = pose.up
        camera.near, camera.far = pose.near, pose.far
        camera.fov = pose.fov
        camera.position = pose.position
        camera.look_at = pose.look_at
        self._pose, self._aspect, self.ortho = pose, self.aspect(), ortho
        if ortho:
            offset = np.subtract(pose.position, pose.look_at)
            distance = float(np.linalg.norm(offset))
            self._axis = (offset / distance, distance)
        # a pose the browser already shows is not reported again: it is back at once
        self._echoed, self._sent = self.reported(pose.position, pose.look_at), time.monotonic()
        self._sent_at = time.time()

    def _moved(self, camera: viser.CameraHandle) -> None:
        """A camera report from the browser (viser runs this in its thread pool)."""
        with self._lock:
            if camera.update_timestamp <= self._sent_at:
                return  # the handle holds the pose sent since: this report is older than it
            self._reported = (np.array(camera.position), np.array(camera.look_at))
            pose = self._pose
            if not self.active or pose is None:
                return
            ours = np.allclose(camera.position, pose.position, rtol=1e-3, atol=1e-3)
            if not self._echoed:
                # a plan zoomed again before the browser reported the last zoom back: no
                # report from before the plan looks along its axis
                self._echoed = ours or (self.ortho and self._turned() <= ORBIT_DEG)
                if not self._echoed:  # a report from before the browser applied the pose
                    if time.monotonic() - self._sent > ECHO_WAIT_S:
                        self._fit = None  # never came back: the browser's camera is the truth
                        self._echoed = True
                    return
            if self._fit is not None:
                if ours:  # only the canvas may have changed
                    if abs(self.aspect() - self._aspect) >= REFIT_ASPECT * self._aspect:
                        self._send(self._fit(self.aspect()))
                    return
                self._fit = None  # the user took over
            if self.ortho:
                self._keep_ortho()
            self._on_user_move()

    def _turned(self) -> float:
        """Degrees between the camera's direction and the plan's or elevation's."""
        if self._axis is None:
            return 180.0
        offset = np.asarray(self.camera.position) - np.asarray(self.camera.look_at)
        cosine = offset @ self._axis[0] / max(float(np.linalg.norm(offset)), 1e-12)
        return math.degrees(math.acos(float(np.clip(cosine, -1.0, 1.0))))

    def _keep_ortho(self) -> None:
        """The user moved a plan or an elevation: a zoom keeps it one, an orbit ends it."""
        assert self._axis is not None
        axis, distance = self._axis
        position, look_at = np.asarray(self.camera.position), np.asarray(self.camera.look_at)
        offset = position - look_at
        now = float(np.linalg.norm(offset))
        half = now * math.tan(float(self.camera.fov) / 2.0)  # what the view spans, kept
        if self._turned() > ORBIT_DEG:
            fov = math.radians(FOV_DEG)
            back = offset / now * half / math.tan(fov / 2.0)
            self._send(CameraPose(_vector(look_at + back), _vector(look_at), fov=fov))
        elif abs(now - distance) > ZOOM_SHARE * distance:
            fov = 2.0 * math.atan(half / distance)
            pose = CameraPose(
                _vector(look_at + axis * distance),
                _vector(look_at),
                fov=fov,
                near=ORTHO_NEAR,
                far=ortho_far(distance),
            )
            self._send(pose, ortho=True)


def _vector(values: Vector) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in np.asarray(values, dtype=np.float64)[:3])
    return (x, y, z)
