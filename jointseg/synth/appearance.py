"""Colours, surface textures and lighting, so synthetic points look like a real RGB scan.

Colour is what colour region growing and the network's colour channels see, so it must be
neither constant per class (too easy) nor random (useless): each object draws a base colour from
a class-plausible distribution, each point gets material texture (wood grain, carpet speckle,
tile grout) and sensor noise, and smooth shading by distance from ceiling lights and by the
surface normal adds the brightness gradients of a real capture.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

# Material codes stored per triangle.
PLAIN, WOOD, CARPET, TILE, CEILING_TILE, FABRIC, GLASS, METAL, LAMP, SCREEN = range(10)

#: Luminance noise amplitude per material (relative).
_NOISE = np.array([0.025, 0.035, 0.07, 0.025, 0.03, 0.05, 0.09, 0.035, 0.02, 0.04])

#: Base-colour palettes in linear-ish sRGB [0, 1]: kind -> list of (centre colour, jitter).
_PALETTES: dict[str, list[tuple[tuple[float, float, float], float]]] = {
    "wall": [
        ((0.86, 0.85, 0.81), 0.03),
        ((0.88, 0.84, 0.74), 0.03),
        ((0.80, 0.80, 0.78), 0.03),
        ((0.84, 0.86, 0.80), 0.03),
        ((0.78, 0.82, 0.86), 0.03),
        ((0.90, 0.88, 0.82), 0.02),
    ],
    "floor": [
        ((0.42, 0.42, 0.44), 0.05),
        ((0.52, 0.38, 0.26), 0.05),
        ((0.70, 0.67, 0.60), 0.05),
        ((0.30, 0.33, 0.42), 0.04),
        ((0.58, 0.55, 0.50), 0.05),
    ],
    "ceiling": [((0.92, 0.92, 0.90), 0.02), ((0.88, 0.88, 0.86), 0.02)],
    "door": [
        ((0.58, 0.40, 0.24), 0.06),
        ((0.70, 0.52, 0.32), 0.05),
        ((0.48, 0.49, 0.52), 0.05),
        ((0.35, 0.45, 0.55), 0.05),
        ((0.40, 0.28, 0.18), 0.04),
    ],
    "frame": [((0.90, 0.90, 0.88), 0.02), ((0.62, 0.63, 0.65), 0.04), ((0.30, 0.30, 0.32), 0.04)],
    "glass": [((0.22, 0.27, 0.32), 0.05), ((0.55, 0.62, 0.68), 0.06), ((0.40, 0.45, 0.42), 0.05)],
    "blind": [((0.55, 0.57, 0.60), 0.04), ((0.36, 0.39, 0.43), 0.04), ((0.70, 0.60, 0.46), 0.04)],
    "whiteboard": [((0.95, 0.95, 0.94), 0.01)],
    "blackboard": [((0.14, 0.24, 0.19), 0.03), ((0.13, 0.13, 0.14), 0.02)],
    "wood": [
        ((0.62, 0.45, 0.28), 0.06),
        ((0.76, 0.62, 0.44), 0.05),
        ((0.45, 0.30, 0.18), 0.04),
    ],
    "desk": [
        ((0.62, 0.45, 0.28), 0.06),
        ((0.78, 0.66, 0.48), 0.05),
        ((0.85, 0.85, 0.83), 0.03),
        ((0.55, 0.56, 0.57), 0.04),
        ((0.25, 0.25, 0.26), 0.03),
    ],
    "metal": [((0.60, 0.61, 0.63), 0.05), ((0.18, 0.18, 0.19), 0.03), ((0.78, 0.78, 0.80), 0.04)],
    "chair": [
        ((0.12, 0.12, 0.13), 0.03),
        ((0.35, 0.36, 0.38), 0.04),
        ((0.20, 0.28, 0.50), 0.05),
        ((0.60, 0.15, 0.14), 0.05),
        ((0.22, 0.45, 0.30), 0.05),
        ((0.85, 0.50, 0.15), 0.05),
        ((0.62, 0.45, 0.28), 0.05),
    ],
    "sofa": [
        ((0.30, 0.20, 0.14), 0.04),
        ((0.15, 0.15, 0.16), 0.03),
        ((0.45, 0.46, 0.48), 0.05),
        ((0.55, 0.16, 0.15), 0.05),
        ((0.22, 0.30, 0.52), 0.05),
        ((0.72, 0.65, 0.52), 0.05),
    ],
    "bookcase": [
        ((0.62, 0.45, 0.28), 0.06),
        ((0.80, 0.70, 0.52), 0.05),
        ((0.88, 0.88, 0.86), 0.03),
        ((0.55, 0.57, 0.60), 0.04),
    ],
    "cabinet": [((0.80, 0.80, 0.78), 0.04), ((0.50, 0.52, 0.55), 0.05), ((0.66, 0.50, 0.33), 0.05)],
    "cardboard": [((0.66, 0.52, 0.34), 0.05)],
    "plant": [((0.20, 0.42, 0.16), 0.06), ((0.30, 0.50, 0.20), 0.06)],
    "pot": [((0.60, 0.32, 0.22), 0.05), ((0.85, 0.85, 0.83), 0.03), ((0.20, 0.20, 0.21), 0.03)],
    "screen": [((0.06, 0.06, 0.07), 0.01)],
    "lamp": [((0.97, 0.97, 0.95), 0.01)],
    "paper": [((0.94, 0.94, 0.92), 0.02)],
    "column": [((0.62, 0.62, 0.62), 0.04), ((0.74, 0.68, 0.58), 0.04), ((0.55, 0.60, 0.66), 0.04)],
}


def sample_colour(rng: np.random.Generator, kind: str, n: int | None = None) -> np.ndarray:
    """Draw base colour(s) from the palette of ``kind``, or vivid ones for ``"any"``/``"book"``.

    Returns an array (3,) for ``n=None``, else (n, 3), values in [0, 1].
    """
    k = 1 if n is None else n
    if kind in ("any", "book"):
        hue = rng.uniform(0.0, 1.0, k)
        sat = rng.uniform(0.15, 0.8 if kind == "book" else 0.6, k)
        val = rng.uniform(0.2, 0.9, k)
        out = _hsv_to_rgb(hue, sat, val)
    else:
        pal = _PALETTES[kind]
        idx = rng.integers(0, len(pal), k)
        centres = np.array([pal[i][0] for i in idx])
        jitter = np.array([pal[i][1] for i in idx])
        out = centres + rng.normal(0.0, 1.0, (k, 3)) * jitter[:, None] * 0.6
        out += rng.normal(0.0, 1.0, (k, 1)) * jitter[:, None]
    out = np.clip(out, 0.02, 1.0)
    return out[0] if n is None else out


def _hsv_to_rgb(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectorised HSV to RGB, all inputs in [0, 1]."""
    i = np.floor(h * 6.0).astype(int) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    table = np.stack(
        [
            np.stack([v, t, p], 1),
            np.stack([q, v, p], 1),
            np.stack([p, v, t], 1),
            np.stack([p, q, v], 1),
            np.stack([t, p, v], 1),
            np.stack([v, p, q], 1),
        ]
    )
    return table[i, np.arange(h.shape[0])]


def _grid_lines(a: np.ndarray, b: np.ndarray, pitch: float, width: float) -> np.ndarray:
    """True where (a, b) lies on a square grid of ``pitch`` with lines ``width`` wide."""
    fa = np.abs(((a / pitch) + 0.5) % 1.0 - 0.5) * pitch
    fb = np.abs(((b / pitch) + 0.5) % 1.0 - 0.5) * pitch
    return (fa < width / 2) | (fb < width / 2)


LightSets = Sequence[tuple[tuple[float, float, float, float], np.ndarray]]


def light_owner(xyz: np.ndarray, light_sets: LightSets) -> np.ndarray:
    """Index of the light set acting on each point: the first rectangle containing it (with a
    30 cm margin for walls), else the one with the nearest centre."""
    x, y = xyz[:, 0], xyz[:, 1]
    owner = np.full(xyz.shape[0], -1, dtype=np.int64)
    for i, (r, _) in enumerate(light_sets):
        inside = (owner < 0) & (x >= r[0] - 0.3) & (x <= r[2] + 0.3)
        inside &= (y >= r[1] - 0.3) & (y <= r[3] + 0.3)
        owner[inside] = i
    rest = owner < 0
    if rest.any():
        centres = np.array([[(r[0] + r[2]) / 2, (r[1] + r[3]) / 2] for r, _ in light_sets])
        d2 = (x[rest, None] - centres[None, :, 0]) ** 2 + (y[rest, None] - centres[None, :, 1]) ** 2
        owner[rest] = np.argmin(d2, axis=1)
    return owner


def nearest_light(xyz: np.ndarray, light_sets: LightSets, owner: np.ndarray) -> np.ndarray:
    """Position of the nearest light of each point's light set, (N, 3); NaN where none."""
    out = np.full(xyz.shape, np.nan)
    for i, (_, lights) in enumerate(light_sets):
        sel = np.flatnonzero(owner == i)
        if sel.size == 0 or len(lights) == 0:
            continue
        lp = np.asarray(lights, dtype=np.float64)
        p = xyz[sel]
        best = np.zeros(sel.size, dtype=np.int64)
        best_d2 = np.full(sel.size, np.inf)
        for k, light in enumerate(lp):  # running minimum keeps memory at O(N)
            d2 = ((p - light) ** 2).sum(axis=1)
            closer = d2 < best_d2
            best[closer], best_d2[closer] = k, d2[closer]
        out[sel] = lp[best]
    return out


def facing_normals(normals: np.ndarray, ray_dirs: np.ndarray) -> np.ndarray:
    """Triangle normals flipped to face the scanner (float32)."""
    nrm = normals.astype(np.float32)
    flip = np.einsum("ij,ij->i", nrm, ray_dirs.astype(np.float32)) > 0
    nrm[flip] *= -1.0
    return nrm


def shade(
    xyz: np.ndarray,
    normals: np.ndarray,
    base: np.ndarray,
    material: np.ndarray,
    light_sets: LightSets,
    owner: np.ndarray,
    shadowed: np.ndarray,
    exposure: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """Turn base colours into observed RGB: texture, lighting and sensor noise, vectorised.

    Parameters
    ----------
    xyz : (N, 3) hit points in the (unrotated) scene frame.
    normals : (N, 3) triangle normals facing the scanner (see :func:`facing_normals`).
    base : (N, 3) float base colour, material : (N,) uint8.
    light_sets : sequence of (rect (x0, y0, x1, y1), lights (L, 3))
        Lamps per space rectangle; ``owner`` (from :func:`light_owner`) says which set lights
        each point, which keeps the cost at N times the lamps of one space.
    shadowed : (N,) bool, the nearest lamp is hidden from the point.
    exposure : (N, 3) per-point gain (per-scanner exposure and white balance).

    Returns
    -------
    (N, 3) uint8
    """
    n = xyz.shape[0]
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    tex = 1.0 + rng.standard_normal(n, dtype=np.float32) * _NOISE[material].astype(np.float32)
    wood = material == WOOD
    if wood.any():
        s = x[wood] * 0.8 + y[wood] * 0.6
        t = z[wood] + 0.4 * (x[wood] - y[wood])
        tex[wood] *= 1.0 + 0.07 * np.sin(2 * np.pi * s / 0.011 + 3.0 * np.sin(2 * np.pi * t / 0.3))
    tile = material == TILE
    if tile.any():
        tex[tile] *= np.where(_grid_lines(x[tile], y[tile], 0.6, 0.006), 0.72, 1.0)
    ctile = material == CEILING_TILE
    if ctile.any():
        tex[ctile] *= np.where(_grid_lines(x[ctile], y[ctile], 0.6, 0.025), 0.86, 1.0)
    carpet = material == CARPET
    if carpet.any():
        tex[carpet] *= 1.0 + 0.05 * np.sin(x[carpet] * 37.0) * np.sin(y[carpet] * 41.0)

    direct = np.zeros(n, dtype=np.float32)
    for i, (_, lights) in enumerate(light_sets):
        sel = np.flatnonzero(owner == i)
        if sel.size == 0 or len(lights) == 0:
            continue
        p = xyz[sel].astype(np.float32)
        ns = normals[sel]
        acc = np.zeros(sel.size, dtype=np.float32)
        for lp in np.asarray(lights, dtype=np.float32):
            d = lp[None, :] - p
            dist2 = np.einsum("ij,ij->i", d, d) + 1e-6
            cos = np.einsum("ij,ij->i", d, ns) / np.sqrt(dist2)
            acc += (0.3 + 0.7 * np.clip(cos, 0.0, 1.0)) / (1.0 + dist2 / 6.0)
        direct[sel] = 1.0 - np.exp(-acc)
    direct[shadowed] *= 0.45
    light = 0.5 + 0.5 * direct
    light[material == LAMP] = 1.0 / 0.95
    rgb = base.astype(np.float32) * (light * tex)[:, None] * exposure.astype(np.float32)
    rgb += rng.standard_normal((n, 3), dtype=np.float32) * 0.012
    return np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)
