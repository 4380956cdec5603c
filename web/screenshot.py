"""The *Screenshot* button: the tab's scene at a chosen size (1x to 3x the canvas), with the
legend and the scale bar, as a PNG download.

The viewer draws the picture itself (:mod:`web.render`) from the nodes it sent to the tab and
the tab's camera, rather than have the browser render it again (viser's ``get_render``): on a
software-rendered browser, reading a 2x canvas back and encoding it alone took longer than the
whole picture takes here, and the plan and the elevations come out truly orthographic. The
legend and the scale bar the page shows over the canvas are drawn in
(:func:`web.overlay.draw_overlay`), and the PNG goes over the tab's websocket.
"""

from __future__ import annotations

import io
import logging
import time
from collections.abc import Callable

import numpy as np
import viser

from web.camera import CameraFollow
from web.overlay import Overlay, draw_overlay
from web.panels import PanelScene
from web.render import draw_scene
from web.tools import ClickTools

log = logging.getLogger(__name__)

#: The scene's background: light blue-grey, so near-white clutter and the yellow ceiling show.
BACKGROUND = (205, 212, 220)
#: The largest image a screenshot may be, pixels (width, height).
MAX_SIZE = (7680, 4320)
#: The sizes offered, as multiples of the canvas.
SIZES = {"1x canvas": 1, "2x canvas": 2, "3x canvas": 3}


def picture(
    panels: PanelScene, tools: ClickTools, camera: CameraFollow, size: tuple[int, int], factor: int
) -> np.ndarray:
    """What the tab shows, drawn at ``size`` (width, height), ``factor`` times the canvas."""
    clouds, lines, labels = panels.drawing()
    marks, measured = tools.drawing(panels.offsets())
    width, height = size
    return draw_scene(
        camera.eye(), width, height, BACKGROUND, clouds, [*lines, *measured], labels, marks, factor
    )


def png_bytes(image: np.ndarray) -> bytes:
    """An (H, W, 3) uint8 image as PNG (fast compression: a screenshot is sent at once)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def send_screenshot(
    client: viser.ClientHandle,
    stem: str,
    draw: Callable[[tuple[int, int], int], np.ndarray],
    canvas: tuple[int, int],
    factor: int,
    overlay: Callable[[int], Overlay],
) -> float:
    """Draw ``factor`` times the ``canvas`` (width, height) with ``draw(size, factor)``, draw
    the overlay in (made for that factor: ``overlay(factor)``), encode and send
    ``<stem>_view.png``; the seconds it took."""
    started = time.perf_counter()
    width = max(min(canvas[0] * factor, MAX_SIZE[0]), 16)
    height = max(min(canvas[1] * factor, MAX_SIZE[1]), 16)
    image = draw((width, height), factor)
    drawn = time.perf_counter()
    image = draw_overlay(image, overlay(factor), float(factor))
    body = png_bytes(image)
    client.send_file_download(f"{stem}_view.png", body, save_immediately=True)
    took = time.perf_counter() - started
    log.info(
        "client %d: screenshot %dx%d in %.2f s (scene %.2f s, legend and PNG %.2f s, %d kB)",
        client.client_id, width, height, took, drawn - started, took - (drawn - started),
        len(body) // 1024,
    )  # fmt: skip
    return took
