"""The *Screenshot* button: the canvas as the browser renders it, at a chosen size, with the
legend and the scale bar, as a PNG download.

viser's ``get_render`` has the browser render the scene again at the size asked (any size its
WebGL allows, so 2x the canvas for print), from the camera's pose, onto a transparent
background; it renders the scene only, so the viewer lays it on its own background colour,
draws the overlay the page shows over the canvas into it (:func:`web.overlay.draw_overlay`),
and sends the PNG over the tab's websocket. ``get_render`` draws with a near plane of 1 cm and a
far one of 1000 m whatever the camera's, which is why the plan's camera stands at most 600 m
away (:data:`web.layout.ORTHO_DISTANCES`).
"""

from __future__ import annotations

import io
import logging
import time
from collections.abc import Callable

import numpy as np
import viser

from web.overlay import Overlay, draw_overlay

log = logging.getLogger(__name__)

#: The scene's background: light blue-grey, so near-white clutter and the yellow ceiling show.
BACKGROUND = (205, 212, 220)
#: The largest image a screenshot may be, pixels (width, height).
MAX_SIZE = (7680, 4320)
#: The sizes offered, as multiples of the canvas.
SIZES = {"1x canvas": 1, "2x canvas": 2, "3x canvas": 3}
#: Seconds the browser has to render one.
RENDER_TIMEOUT_S = 30.0


def render(client: viser.ClientHandle, width: int, height: int) -> np.ndarray | None:
    """The canvas rendered by the browser at ``width`` x ``height``, on :data:`BACKGROUND`,
    (H, W, 3) uint8; None (and a notification) when the browser did not answer."""
    width, height = max(min(width, MAX_SIZE[0]), 16), max(min(height, MAX_SIZE[1]), 16)
    try:
        rgba = client.get_render(height, width, transport_format="png", timeout=RENDER_TIMEOUT_S)
    except (TimeoutError, RuntimeError) as exc:
        client.add_notification("Screenshot failed", str(exc), color="red")
        return None
    if rgba.shape[-1] != 4:
        return np.ascontiguousarray(rgba[..., :3])
    # the background renders transparent: lay it on ours, in integers (a float blend of a 2x
    # canvas took 1.7 s of a 3 s screenshot on a loaded machine; this one 0.2 s)
    alpha = rgba[..., 3:4].astype(np.uint16)
    ours = np.array(BACKGROUND, np.uint16) * (255 - alpha)
    return ((rgba[..., :3] * alpha + ours + 127) // 255).astype(np.uint8)


def png_bytes(image: np.ndarray) -> bytes:
    """An (H, W, 3) uint8 image as PNG (fast compression: a screenshot is sent at once)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def send_screenshot(
    client: viser.ClientHandle,
    stem: str,
    canvas: tuple[int, int],
    factor: int,
    overlay: Callable[[int], Overlay],
) -> float:
    """Render ``factor`` times the ``canvas`` (width, height), draw the overlay (made for the
    image's metres per pixel factor: ``overlay(factor)``), encode and send
    ``<stem>_view.png``; the seconds it took (0 when it failed)."""
    started = time.perf_counter()
    width, height = canvas[0] * factor, canvas[1] * factor
    image = render(client, width, height)
    if image is None:
        return 0.0
    rendered = time.perf_counter()
    image = draw_overlay(image, overlay(factor), float(factor))
    body = png_bytes(image)
    client.send_file_download(f"{stem}_view.png", body, save_immediately=True)
    took = time.perf_counter() - started
    log.info(
        "client %d: screenshot %dx%d in %.2f s (render %.2f s, legend and PNG %.2f s, %d kB)",
        client.client_id, image.shape[1], image.shape[0], took, rendered - started,
        took - (rendered - started), len(body) // 1024,
    )  # fmt: skip
    return took
