"""The legend and the scale bar over the canvas, and the same drawn into screenshots.

viser has no overlay on its canvas (its GUI lives in panels beside it), so the viewer places one
itself: a hidden element of the control panel (:func:`web.view_state.script_html`) puts a
``<div>`` over the canvas's corner, which the page draws above the scene; it takes no clicks.
A screenshot is drawn by the viewer (:mod:`web.render`), without the page around
the canvas, so :func:`draw_overlay` draws the same legend and bar into the image.

The **scale bar** is shown in the plan and the elevations only: there the camera stands in for
an orthographic one (:mod:`web.camera`), so a metre is the same length everywhere on the screen;
in a perspective view a bar would be true at one depth only, so none is drawn.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

from jointseg.classes import PALETTE, UNLABELLED_COLOUR
from web.legend import class_title, present_classes
from web.scene import SceneData
from web.view_state import script_html

#: Layout of the legend box, CSS pixels (a screenshot at 2x the canvas draws it twice as big).
MARGIN, PADDING, SWATCH, ROW, FONT = 12, 6, 12, 18, 12
#: The scale bar: its height and the length it aims at, CSS pixels.
BAR_HEIGHT, BAR_TARGET = 5, 140
#: The box's width, CSS pixels: wide enough for the longest class name.
BOX_WIDTH = 150

Colour = tuple[int, int, int]


@dataclass(frozen=True)
class ScaleBar:
    """A round length (1, 2 or 5 times a power of ten metres) and its length as a share of the
    picture's height (the same on the page, whatever its pixels, and in a screenshot)."""

    metres: float
    share: float

    @property
    def label(self) -> str:
        """``2 m``, ``50 cm``, ``5 mm``."""
        if self.metres >= 1.0:
            return f"{self.metres:g} m"
        if self.metres >= 0.01:
            return f"{self.metres * 100:g} cm"
        return f"{self.metres * 1000:g} mm"


@dataclass(frozen=True)
class Overlay:
    """What the overlay shows: the classes drawn (name and colour) and the scale bar."""

    entries: tuple[tuple[str, Colour], ...] = ()
    bar: ScaleBar | None = None

    @property
    def empty(self) -> bool:
        """Nothing to show (no job)."""
        return not self.entries and self.bar is None


def legend_entries(present: list[int], hidden: set[int]) -> tuple[tuple[str, Colour], ...]:
    """The classes drawn now (present and not hidden), in palette order, with their colour."""
    out = []
    for cls in present:
        if cls in hidden:
            continue
        rgb = UNLABELLED_COLOUR if cls < 0 else PALETTE[cls]
        out.append((class_title(cls), (int(rgb[0]), int(rgb[1]), int(rgb[2]))))
    return tuple(out)


def overlay_of(
    data: SceneData | None, hidden: set[int], span: float | None, height: int
) -> Overlay:
    """What the overlay shows for a job: the classes drawn and, given the metres the canvas's
    height spans (a plan's or an elevation's: None in a perspective view) and its pixels, a
    scale bar (the same share of the height in a screenshot of any size)."""
    if data is None:
        return Overlay()
    entries = legend_entries(present_classes(data.counts), hidden)
    return Overlay(entries, None if span is None else scale_bar(span, height))


def scale_bar(span: float, height: int) -> ScaleBar | None:
    """The round length nearest below :data:`BAR_TARGET` CSS pixels of a picture ``height``
    pixels high whose height spans ``span`` metres (None without a scale)."""
    if not span > 0 or not math.isfinite(span) or height <= 0:
        return None
    raw = BAR_TARGET * span / height
    power = 10.0 ** math.floor(math.log10(raw))
    metres = max(m * power for m in (1, 2, 5) if m * power <= raw)
    return ScaleBar(metres, metres / span)


def layout(overlay: Overlay, height: int, scale: float = 1.0) -> dict[str, tuple[int, ...]]:
    """Where each part goes in an image ``height`` pixels high (``scale``: image pixels per CSS
    pixel): ``box`` (x0, y0, x1, y1), ``swatch<i>`` and ``text<i>`` per entry, ``bar`` and
    ``bar_text``; anchored at the bottom left corner."""

    def px(value: float) -> int:
        return int(round(value * scale))

    rows = len(overlay.entries)
    bar_rows = 2 if overlay.bar is not None else 0
    inner = rows * ROW + bar_rows * ROW
    bottom = height - px(MARGIN)
    top = bottom - px(inner + 2 * PADDING)
    left = px(MARGIN)
    length = 0 if overlay.bar is None else int(round(overlay.bar.share * height))
    width = max(BOX_WIDTH, length / scale + 2 * PADDING)
    parts: dict[str, tuple[int, ...]] = {"box": (left, top, left + px(width), bottom)}
    for i in range(rows):
        y = top + px(PADDING + i * ROW + (ROW - SWATCH) / 2)
        parts[f"swatch{i}"] = (left + px(PADDING), y, left + px(PADDING + SWATCH), y + px(SWATCH))
        parts[f"text{i}"] = (left + px(2 * PADDING + SWATCH), top + px(PADDING + i * ROW))
    if overlay.bar is not None:
        y = top + px(PADDING + rows * ROW)
        parts["bar_text"] = (left + px(PADDING), y)
        bar_top = y + px(ROW + (ROW - BAR_HEIGHT) / 2)
        parts["bar"] = (
            left + px(PADDING),
            bar_top,
            left + px(PADDING) + length,
            bar_top + px(BAR_HEIGHT),
        )
    return parts


def overlay_html(overlay: Overlay, serial: int) -> str:
    """The hidden element that puts (or takes away) the overlay over the page's canvas."""
    body = "" if overlay.empty else _markup(overlay)
    script = (
        "var cs=document.getElementsByTagName('canvas'),c=null;"
        "for(var i=0;i<cs.length;i++){var a=cs[i];"
        "if(!c||a.clientWidth*a.clientHeight>c.clientWidth*c.clientHeight)c=a;}"
        "var o=document.getElementById('jointseg-overlay');"
        f"if(!c||!{json.dumps(body)}){{if(o)o.remove();}}else{{"
        "var p=c.parentElement;"
        "if(!o){o=document.createElement('div');o.id='jointseg-overlay';}"
        "if(o.parentElement!==p)p.appendChild(o);"
        "if(getComputedStyle(p).position==='static')p.style.position='relative';"
        f"o.style.cssText={json.dumps(_box_css())};"
        f"o.innerHTML={json.dumps(body)};"
        # the bar's length: its share of the canvas's height, in the page's own pixels
        "var b=o.querySelector('.jointseg-bar');"
        "if(b)b.style.width=(b.dataset.share*c.clientHeight).toFixed(1)+'px';}"
    )
    return script_html(script, serial, "overlay")


def _box_css() -> str:
    return (
        f"position:absolute;left:{MARGIN}px;bottom:{MARGIN}px;min-width:{BOX_WIDTH}px;"
        f"padding:{PADDING}px;box-sizing:border-box;background:#fff;border:1px solid #888;"
        f"font:{FONT}px/{ROW}px sans-serif;color:#222;pointer-events:none;z-index:5"
    )


def _markup(overlay: Overlay) -> str:
    rows = [
        f'<div class="jointseg-legend-row"><span style="display:inline-block;width:{SWATCH}px;'
        f"height:{SWATCH}px;margin-right:{PADDING}px;vertical-align:-1px;"
        f'background:rgb{rgb}"></span>{name}</div>'
        for name, rgb in overlay.entries
    ]
    if overlay.bar is not None:
        rows.append(f'<div class="jointseg-scale">{overlay.bar.label}</div>')
        rows.append(
            f'<div style="height:{ROW}px"><div class="jointseg-bar" '
            f'data-share="{overlay.bar.share:.6f}" style="display:inline-block;'
            f'height:{BAR_HEIGHT}px;background:#222;vertical-align:middle"></div></div>'
        )
    return "".join(rows)


def draw_overlay(image: np.ndarray, overlay: Overlay, scale: float) -> np.ndarray:
    """``image`` (H, W, 3) uint8 with the legend and the scale bar drawn in its bottom left
    corner as the page shows them, ``scale`` image pixels per CSS pixel."""
    if overlay.empty:
        return image
    from PIL import Image, ImageDraw, ImageFont

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    font = ImageFont.load_default(size=max(FONT * scale, 6))
    parts = layout(overlay, image.shape[0], scale)
    draw.rectangle(parts["box"], fill=(255, 255, 255), outline=(136, 136, 136), width=1)
    for i, (name, rgb) in enumerate(overlay.entries):
        x0, y0, x1, y1 = parts[f"swatch{i}"]
        draw.rectangle((x0, y0, x1 - 1, y1 - 1), fill=rgb)
        draw.text(_xy(parts[f"text{i}"]), name, fill=(34, 34, 34), font=font)
    if overlay.bar is not None:
        draw.text(_xy(parts["bar_text"]), overlay.bar.label, fill=(34, 34, 34), font=font)
        x0, y0, x1, y1 = parts["bar"]
        draw.rectangle((x0, y0, x1 - 1, y1 - 1), fill=(34, 34, 34))
    return np.asarray(picture)


def _xy(values: tuple[int, ...]) -> tuple[float, float]:
    return float(values[0]), float(values[1])
