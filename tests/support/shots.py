"""Reading the viewer's screenshots: where the panels are, which palette colours they show.

The viewer draws points with flat shading, so a class's points appear in exactly its palette
colour; the background is one flat colour (read from the canvas's corners, so the tests hold
whatever it is). Panels are separated by empty columns of pixels.
"""

from __future__ import annotations

import io
import time
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from jointseg.classes import NUM_CLASSES, PALETTE

#: The browser tests' window: 16:9, small enough that chromium's CPU WebGL (SwiftShader) draws
#: and screenshots it faster (`pytest -m browser` 15 % faster than at 1600 x 900); what the tests
#: read (panel layout, palette colours, clicks) holds at this size but for WIDE_VIEWPORT's tests.
VIEWPORT = {"width": 1120, "height": 630}
#: The window of the tests that count five to seven panels or compare their ink: at the smaller
#: size a panel is 150 pixels wide and its points' sprites overlap too much to tell apart.
WIDE_VIEWPORT = {"width": 1600, "height": 900}

#: Hides viser's toasts ("software WebGL rendering detected") and the viewer's legend over the
#: canvas from the screenshots (their panels' columns are read; the legend's tests show it).
HIDE_OVERLAYS = '[class*="mantine-Notifications"], #jointseg-overlay { display: none !important; }'


def canvas_box(page: Any) -> dict[str, float]:
    """The 3D canvas's rectangle in the page (the control panel is docked to its right)."""
    canvases = page.locator("canvas")
    boxes = [canvases.nth(i).bounding_box() for i in range(canvases.count())]
    box = max((b for b in boxes if b), key=lambda b: b["width"] * b["height"])
    return {k: box[k] for k in ("x", "y", "width", "height")}


def grab(page: Any, path: Path | None = None) -> np.ndarray:
    """The canvas as an (H, W, 3) uint8 array (saved as PNG to ``path`` when given)."""
    png = page.screenshot(clip=canvas_box(page))
    if path is not None:
        path.write_bytes(png)
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def settled(page: Any, *, timeout: float = 30.0, min_ink: int = 20_000) -> np.ndarray:
    """Wait until the canvas shows at least ``min_ink`` drawn pixels (more than the panel
    titles alone) and has not changed for three grabs; return it."""
    deadline = time.monotonic() + timeout
    last, same = grab(page), 0
    while time.monotonic() < deadline:
        time.sleep(0.5)
        now = grab(page)
        same = same + 1 if np.array_equal(now, last) else 0
        if same >= 2 and ink(now).sum() >= min_ink:
            return now
        last = now
    raise AssertionError(f"the viewer did not settle within {timeout} s")


def background(image: np.ndarray) -> np.ndarray:
    """The background colour: the commonest colour of the canvas's four corners, (3,) int16."""
    h, w = image.shape[:2]
    corners = [image[6:16, 6:16], image[6:16, w - 16 : w - 6]]
    corners += [image[h - 16 : h - 6, 6:16], image[h - 16 : h - 6, w - 16 : w - 6]]
    pixels = np.concatenate([c.reshape(-1, 3) for c in corners]).astype(np.int16)
    colours, counts = np.unique(pixels, axis=0, return_counts=True)
    return colours[int(np.argmax(counts))]


def ink(image: np.ndarray) -> np.ndarray:
    """Pixels that are not (nearly) the background colour, (H, W) bool."""
    return np.abs(image.astype(np.int16) - background(image)).max(axis=2) > 10


def panel_spans(image: np.ndarray, count: int, *, min_gap: int = 2) -> list[tuple[int, int]]:
    """Column ranges [start, stop) of the ``count`` panels, left to right.

    Runs of columns with ink separated by fewer than ``min_gap`` empty columns are one run;
    the narrowest gaps are closed until ``count`` runs remain. The canvas's outer 4 pixel
    columns (its border) are ignored.
    """
    filled = ink(image).sum(axis=0) > 2
    filled[:4] = filled[-4:] = False
    runs: list[list[int]] = []
    gap = min_gap
    for x, on in enumerate(filled):
        if not on:
            gap += 1
            continue
        if runs and gap < min_gap:
            runs[-1][1] = x + 1
        else:
            runs.append([x, x + 1])
        gap = 0
    while len(runs) > count:
        i = int(np.argmin([runs[j + 1][0] - runs[j][1] for j in range(len(runs) - 1)]))
        runs[i : i + 2] = [[runs[i][0], runs[i + 1][1]]]
    if len(runs) != count:
        raise AssertionError(f"expected {count} panels, found {len(runs)} column runs {runs}")
    return [(a, b) for a, b in runs]


def palette_pixels(image: np.ndarray, span: tuple[int, int]) -> np.ndarray:
    """Pixels of each class's exact palette colour inside a panel's columns, (NUM_CLASSES,)."""
    part = image[:, span[0] : span[1]].reshape(-1, 3).astype(np.int32)
    codes = (part[:, 0] << 16) | (part[:, 1] << 8) | part[:, 2]
    palette = PALETTE.astype(np.int32)
    wanted = (palette[:, 0] << 16) | (palette[:, 1] << 8) | palette[:, 2]
    return np.array([int(np.count_nonzero(codes == w)) for w in wanted[:NUM_CLASSES]])
