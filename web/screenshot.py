"""The *Screenshot* button: the canvas as the browser renders it, as a PNG download.

viser's ``get_render`` has the browser render the scene again at the size asked, from the
camera's pose, onto a transparent background; the viewer lays it on its own background colour
and sends the PNG over the tab's websocket.
"""

from __future__ import annotations

import io
import logging
import time

import numpy as np
import viser

log = logging.getLogger(__name__)

#: The scene's background: light blue-grey, so near-white clutter and the yellow ceiling show.
BACKGROUND = (205, 212, 220)
#: The largest image a screenshot may be, pixels (width, height).
MAX_SIZE = (7680, 4320)
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
    image = rgba[..., :3].astype(np.float64)
    if rgba.shape[-1] == 4:  # the background renders transparent: lay it on ours
        alpha = rgba[..., 3:4].astype(np.float64) / 255.0
        image = image * alpha + np.array(BACKGROUND, np.float64) * (1.0 - alpha)
    return np.round(image).astype(np.uint8)


def png_bytes(image: np.ndarray) -> bytes:
    """An (H, W, 3) uint8 image as PNG (fast compression: a screenshot is sent at once)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def send_screenshot(client: viser.ClientHandle, stem: str, width: int, height: int) -> float:
    """Render, encode and send ``<stem>_view.png``; the seconds it took (0 when it failed)."""
    started = time.perf_counter()
    image = render(client, width, height)
    if image is None:
        return 0.0
    client.send_file_download(f"{stem}_view.png", png_bytes(image), save_immediately=True)
    took = time.perf_counter() - started
    log.info("client %d: screenshot %dx%d in %.2f s", client.client_id, width, height, took)
    return took
