"""Pictures of a tab's scene drawn by the viewer itself, from the tab's camera, at any size.

A screenshot could be the browser's own render (viser's ``get_render``), but on a browser that
renders WebGL in software (chromium's SwiftShader: a weak client's lot, and the test machines')
reading a 2x canvas back and encoding it took 1.5 to 2 s of a 2.3 to 3.3 s render of a
70 000-point room, with the page around the canvas (the legend) still to draw. The viewer holds
every node it sent, so it draws them itself, as the browser does: points as flat squares
(viser's ``gl_PointSize`` is ``point_size * height / tan(fov / 2) / depth`` pixels, twice the
projected size), nearest point first (a depth buffer); then object boxes and measurement lines
at their screen thickness, marks, and the panels' titles in white boxes. Lines and marks are
drawn over the points (the browser hides what lies behind a point).

In the plan and the elevations, whose live camera only stands in for an orthographic one
(:mod:`web.camera`), the picture is truly orthographic: the scale at the look-at point holds
everywhere.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

#: Largest point square drawn, pixels (a point nearer the camera is drawn no bigger).
MAX_SIDE = 48
#: The titles' font size (viser's 1.4 screen scale), CSS pixels.
TITLE_FONT = 17
#: Nearest depth drawn, metres (viser's near plane).
NEAR = 0.01


@dataclass(frozen=True)
class Eye:
    """A camera to draw from: its pose, vertical field of view (radians), orthographic or not."""

    position: np.ndarray
    look_at: np.ndarray
    fov: float
    ortho: bool = False
    up: tuple[float, float, float] = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class Cloud:
    """Points to draw: (N, 3) world coordinates, (N, 3) uint8 colours, viser's point size."""

    xyz: np.ndarray
    colours: np.ndarray
    size: float


@dataclass(frozen=True)
class Lines:
    """Segments to draw: (E, 2, 3) world coordinates, their colours ((E, 2, 3) or one (3,) for
    all), screen thickness."""

    ends: np.ndarray
    colours: np.ndarray
    thickness: float


@dataclass(frozen=True)
class Label:
    """A title: its text and world position (anchored at its bottom centre)."""

    text: str
    position: np.ndarray


#: A mark: its world position, its radius in metres, its colour.
Mark = tuple[np.ndarray, float, tuple[int, int, int]]


class Projection:
    """World points to pixels of a ``width`` x ``height`` image seen by ``eye``."""

    def __init__(self, eye: Eye, width: int, height: int) -> None:
        self.eye, self.width, self.height = eye, width, height
        offset = np.asarray(eye.look_at, np.float64) - np.asarray(eye.position, np.float64)
        self.focus = max(float(np.linalg.norm(offset)), 1e-9)
        self.forward = offset / self.focus
        right = np.cross(self.forward, np.asarray(eye.up, np.float64))
        if np.linalg.norm(right) < 1e-9:  # looking along up: any right angle to it
            right = np.cross(self.forward, [0.0, 1.0, 0.0])
        self.right = right / np.linalg.norm(right)
        self.up = np.cross(self.right, self.forward)
        self.focal = (height / 2.0) / math.tan(eye.fov / 2.0)

    def __call__(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Column, row, depth and pixels per metre of (N, 3) points."""
        rel = np.asarray(xyz, np.float64) - np.asarray(self.eye.position, np.float64)
        depth = rel @ self.forward
        safe = np.maximum(depth, NEAR)
        scale = (
            np.full_like(depth, self.focal / self.focus) if self.eye.ortho else self.focal / safe
        )
        column = self.width / 2.0 + (rel @ self.right) * scale
        row = self.height / 2.0 - (rel @ self.up) * scale
        return column, row, depth, scale


def draw_scene(
    eye: Eye,
    width: int,
    height: int,
    background: tuple[int, int, int],
    clouds: Iterable[Cloud],
    lines: Iterable[Lines] = (),
    labels: Iterable[Label] = (),
    marks: Iterable[Mark] = (),
    factor: float = 1.0,
) -> np.ndarray:
    """The scene as an (H, W, 3) uint8 image: points, then lines, marks (world position, world
    radius, colour) and labels; ``factor``: image pixels per CSS pixel (thicknesses, fonts)."""
    project = Projection(eye, width, height)
    image = np.empty((height * width, 3), np.uint8)
    image[:] = background
    depth_buffer = np.full(height * width, np.inf, np.float32)
    for cloud in clouds:
        _splat(project, image, depth_buffer, cloud)
    picture = image.reshape(height, width, 3)
    return _draw_over(project, picture, list(lines), list(marks), list(labels), factor)


def _splat(project: Projection, image: np.ndarray, depth: np.ndarray, cloud: Cloud) -> None:
    """A cloud's points as squares into ``image`` (flat, H * W rows), nearest first."""
    if cloud.xyz.shape[0] == 0:
        return
    column, row, z, scale = project(cloud.xyz)
    side = np.clip(np.rint(2.0 * cloud.size * scale), 1, MAX_SIDE).astype(np.int32)
    ahead = z > NEAR
    x0 = np.floor(column - side / 2.0).astype(np.int64)
    y0 = np.floor(row - side / 2.0).astype(np.int64)
    z32 = z.astype(np.float32)
    for s in np.unique(side[ahead]):
        group = np.flatnonzero(ahead & (side == s))
        offsets = [(dx, dy) for dy in range(int(s)) for dx in range(int(s))]
        for paint in (False, True):  # the nearest depth per pixel first, then its colour
            for dx, dy in offsets:
                x, y = x0[group] + dx, y0[group] + dy
                inside = (x >= 0) & (x < project.width) & (y >= 0) & (y < project.height)
                rows = group[inside]
                index = y[inside] * project.width + x[inside]
                if not paint:
                    np.minimum.at(depth, index, z32[rows])
                    continue
                won = depth[index] == z32[rows]
                image[index[won]] = cloud.colours[rows[won]]


def _draw_over(
    project: Projection,
    picture: np.ndarray,
    lines: list[Lines],
    marks: list[Mark],
    labels: list[Label],
    factor: float,
) -> np.ndarray:
    from PIL import Image, ImageDraw, ImageFont

    canvas = Image.fromarray(picture)
    draw = ImageDraw.Draw(canvas)
    for segment in lines:
        ends = segment.ends.reshape(-1, 3)
        column, row, z, _ = project(ends)
        width = max(1, int(round(segment.thickness * factor)))
        # one colour per end, or one (3,) for the whole set (as viser takes a selected box's)
        colours = np.broadcast_to(segment.colours, segment.ends.shape).reshape(-1, 3)
        for i in range(0, ends.shape[0], 2):
            if z[i] > NEAR and z[i + 1] > NEAR:
                rgb = tuple(int(c) for c in colours[i])
                xy = [(float(column[i]), float(row[i])), (float(column[i + 1]), float(row[i + 1]))]
                draw.line(xy, fill=rgb, width=width)  # type: ignore[arg-type]
    for centre, radius, rgb in marks:
        column, row, z, scale = project(np.asarray(centre, np.float64)[None, :])
        if z[0] > NEAR:
            r = max(2.0, float(radius * scale[0]))
            x, y = float(column[0]), float(row[0])
            draw.ellipse((x - r, y - r, x + r, y + r), fill=rgb)
    font = ImageFont.load_default(size=TITLE_FONT * factor)
    for label in labels:
        column, row, z, _ = project(np.asarray(label.position, np.float64)[None, :])
        if z[0] > NEAR:
            x, y = float(column[0]), float(row[0])
            left, top, right, bottom = draw.textbbox((x, y), label.text, font=font, anchor="mb")
            pad = 3 * factor
            draw.rectangle((left - pad, top - pad, right + pad, bottom + pad), fill=(255, 255, 255))
            draw.text((x, y), label.text, fill=(20, 20, 20), font=font, anchor="mb")
    return np.asarray(canvas)
