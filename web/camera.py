"""A tab's camera: placed by the viewer, kept fitted to the canvas until the user moves it.

viser reports a browser's camera (its pose and canvas size) before it calls the viewer's
``on_client_connect``, so a view's camera and canvas are known from its first moment; the
browser then reports every change, the user's and the viewer's own, a few times a second.

Two things are read from those reports:

- whether the **user took over**: the overview is re-fitted whenever the canvas changes shape
  (the control panel docks, the window is resized) until the user moves the camera. Reports
  sent before the browser applied the viewer's pose still carry the old one, so the user is
  taken to have moved only once the viewer's pose has come back and then changed;
- whether the browser **applied a pose**: setting a pose on viser's camera handle changes the
  server's copy at once, so only a report says what the browser draws (a click aimed through a
  pose the browser has not applied yet goes through the old one).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np
import viser

from web.layout import CameraPose

#: Canvas width / height assumed while the canvas has no size (a hidden tab).
DEFAULT_ASPECT = 16 / 9
#: Seconds the browser has to report back a pose the viewer set.
ECHO_WAIT_S = 3.0
#: Relative change of the canvas's aspect that re-fits a following camera.
REFIT_ASPECT = 0.01

Vector = Sequence[float] | np.ndarray


class CameraFollow:
    """The camera of one tab: the poses the viewer sets and what the browser reports back.

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
        self._lock = lock
        self._on_user_move = on_user_move
        self._fit: Callable[[float], CameraPose] | None = None  # set while the camera follows
        self._pose: CameraPose | None = None  # the last pose sent
        self._aspect = 0.0  # the canvas's aspect when it was sent
        self._echoed = False  # the browser has reported it back
        self._sent = 0.0
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

    def follow(self, fit: Callable[[float], CameraPose]) -> None:
        """Place the camera where ``fit`` puts it for the canvas's aspect, and again whenever the
        canvas changes shape, until the user moves it."""
        with self._lock:
            self._fit = fit
            self._send(fit(self.aspect()))

    def place(self, position: Vector, look_at: Vector, *, fov: float | None = None) -> None:
        """Put the camera at a pose (a link's, a preset's); it no longer follows the canvas."""
        with self._lock:
            self._fit = None
            pose = CameraPose(
                position=_vector(position),
                look_at=_vector(look_at),
                fov=float(self.camera.fov) if fov is None else fov,
            )
            self._send(pose)

    def release(self) -> None:
        """Stop following the canvas (the camera stays where it is)."""
        self._fit = None

    def reported(self, position: Vector, look_at: Vector, *, atol: float = 1e-3) -> bool:
        """Whether the browser last reported the camera at this pose (it applied it)."""
        seen = self._reported
        return (
            seen is not None
            and np.allclose(seen[0], position, atol=atol)
            and np.allclose(seen[1], look_at, atol=atol)
        )

    def pixel_size(self, at: np.ndarray) -> float:
        """Metres one pixel spans at the distance of the camera's look-at point from ``at``."""
        width, height = self.canvas()
        if height <= 0:
            return 0.0
        focus = float(np.linalg.norm(np.asarray(self.camera.look_at) - at))
        return 2.0 * focus * math.tan(float(self.camera.fov) / 2.0) / height

    def _send(self, pose: CameraPose) -> None:
        camera = self.camera
        camera.up_direction = pose.up
        camera.fov = pose.fov
        camera.position = pose.position
        camera.look_at = pose.look_at
        self._pose, self._aspect = pose, self.aspect()
        self._echoed, self._sent = False, time.monotonic()

    def _moved(self, camera: viser.CameraHandle) -> None:
        """A camera report from the browser (viser runs this in its thread pool)."""
        self._reported = (np.array(camera.position), np.array(camera.look_at))
        with self._lock:
            if not self.active:
                return
            fit, pose = self._fit, self._pose
            if fit is None:
                self._on_user_move()
                return
            if pose is not None:
                ours = np.allclose(camera.position, pose.position, rtol=1e-3, atol=1e-3)
                if self._echoed and not ours:
                    self._fit = None  # the user took over
                    self._on_user_move()
                    return
                if not self._echoed:
                    self._echoed = ours
                    if not ours and time.monotonic() - self._sent > ECHO_WAIT_S:
                        self._fit = None  # never came back: stop fighting the browser
                        return
                if abs(self.aspect() - self._aspect) < REFIT_ASPECT * self._aspect:
                    return
            self._send(fit(self.aspect()))


def _vector(values: Vector) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in np.asarray(values, dtype=np.float64)[:3])
    return (x, y, z)
