"""Training augmentation: what other sensors, other rooms and partial scans do to a crop.

Users' scans come from many scanners: denser or sparser than S3DIS, a slice or a corner of a
room, a tilted tripod, another white balance or no colour at all. A network that saw only
S3DIS's dense, level, whole rooms is thrown by each of these, so the crops it trains on get
them at random:

- point density: the region around a crop centre is grid-sub-sampled at 1-6 cm before cropping
  (:func:`density_sample`);
- partial rooms and slices: a vertical cut drops one side of the region, or only a horizontal
  band near the floor is kept (:func:`cut_region`);
- geometry: rotation about z, a mirror, anisotropic scale, a tilt of a few degrees (what the
  frame stage leaves after levelling), an elastic field, sensor noise of up to a few mm
  (:func:`augment`);
- handheld sensors: no ceiling, occlusion holes (:func:`sensor_gaps`);
- stray points: a few points far outside the crop (returns through windows, off mirrors), left
  unlabelled (:func:`add_stray_points`);
- colour: brightness, exposure (a gamma: dim rooms), per-channel gain and offset (white
  balance, and a strong cast for some), contrast, noise; some crops grey, some without colour
  (:func:`augment_colour`).
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy import ndimage

from jointseg.voxels import cell_majority, cell_means, voxel_index

#: The ceiling's class index (S3DIS order).
CEILING = 0
#: Elastic distortion: a random displacement field on a grid of this pitch (m), smoothed over
#: neighbouring grid cells, scaled to about this many metres of displacement.
ELASTIC_PITCH = 0.4
ELASTIC_MAGNITUDE = 0.02


class AugmentParams(BaseModel):
    """How often and how strongly each augmentation applies (stored in the model card)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    elastic: float = Field(0.3, ge=0, le=1, description="share of crops given an elastic field")
    density: float = Field(
        0.5, ge=0, le=1, description="share of crops grid-sub-sampled at a random 1-6 cm first"
    )
    density_range: tuple[float, float] = Field(
        (0.01, 0.06), description="grid sizes (m) drawn for the density augmentation"
    )
    partial: float = Field(0.15, ge=0, le=1, description="share of crops cut by a vertical plane")
    slice: float = Field(
        0.1, ge=0, le=1, description="share of crops keeping only a band above the floor"
    )
    slice_height: tuple[float, float] = Field(
        (0.6, 1.8), description="height (m) of the kept band above the lowest point"
    )
    tilt_degrees: float = Field(3.0, ge=0, le=15, description="largest tilt off vertical")
    colour_drop: float = Field(
        0.05, ge=0, le=1, description="share of crops without colour (all zero, as a bare scan)"
    )
    grey: float = Field(0.1, ge=0, le=1, description="share of crops turned grey")
    noise: tuple[float, float] = Field(
        (0.001, 0.005),
        description="standard deviation (m) of the per-point jitter, drawn per crop in this "
        "range: SLAM and low-cost sensors are a few mm noisy",
    )
    exposure: float = Field(
        0.3, ge=0, le=1, description="share of crops given an exposure change (a gamma)"
    )
    gamma_range: tuple[float, float] = Field(
        (0.7, 1.8), description="gammas drawn for the exposure change (above 1: darker)"
    )
    no_ceiling: float = Field(
        0.15,
        ge=0,
        le=1,
        description="share of crops without their ceiling points (phone LiDAR and RGB-D "
        "captures seldom reach the ceiling)",
    )
    holes: float = Field(
        0.2, ge=0, le=1, description="share of crops with occlusion holes (points in balls gone)"
    )
    hole_radius: tuple[float, float] = Field(
        (0.15, 0.5), description="radius (m) of each of the one to four holes"
    )
    colour_cast: float = Field(
        0.15,
        ge=0,
        le=1,
        description="share of crops given a strong colour cast (a camera's white balance off "
        "under warm or cold light)",
    )
    cast_range: tuple[float, float] = Field(
        (0.7, 1.3), description="per-channel gains drawn for the colour cast"
    )
    stray: float = Field(
        0.1, ge=0, le=1, description="share of crops given a few stray points far outside"
    )
    stray_share: float = Field(
        0.005, ge=0, le=0.1, description="stray points added, as a share of the crop's points"
    )


def elastic_distortion(
    xyz: np.ndarray,
    rng: np.random.Generator,
    pitch: float = ELASTIC_PITCH,
    magnitude: float = ELASTIC_MAGNITUDE,
) -> np.ndarray:
    """Points moved by a smooth random field: walls bow and tables tilt a little, as in real
    scans whose registration is not perfect (grid noise, box-smoothed, trilinearly sampled)."""
    lo = xyz.min(axis=0) - pitch
    shape = tuple(int(n) for n in np.ceil((xyz.max(axis=0) - lo) / pitch) + 3)
    moved = xyz.astype(np.float32).copy()
    coords = ((xyz - lo) / pitch).T
    for axis in range(3):
        field = ndimage.uniform_filter(rng.normal(0, 1, shape), size=3, mode="nearest")
        field *= magnitude / max(float(field.std()), 1e-6)
        moved[:, axis] += ndimage.map_coordinates(field, coords, order=1, mode="nearest")
    return moved


def tilt_matrix(rng: np.random.Generator, max_degrees: float) -> np.ndarray:
    """A rotation by up to ``max_degrees`` about a random horizontal axis (a tripod off level)."""
    angle = np.deg2rad(rng.uniform(-max_degrees, max_degrees))
    phi = rng.uniform(0, 2 * np.pi)
    ax, ay = np.cos(phi), np.sin(phi)
    c, s = np.cos(angle), np.sin(angle)
    # Rodrigues' formula for the unit axis (ax, ay, 0)
    return np.array(
        [
            [c + ax * ax * (1 - c), ax * ay * (1 - c), ay * s],
            [ax * ay * (1 - c), c + ay * ay * (1 - c), -ax * s],
            [-ay * s, ax * s, c],
        ],
        dtype=np.float32,
    )


def augment_colour(rgb: np.ndarray, rng: np.random.Generator, params: AugmentParams) -> np.ndarray:
    """Brightness, per-channel gain and offset (white balance), contrast about the mean, noise;
    a share of crops grey and a share with no colour at all."""
    if rng.random() < params.colour_drop:
        return np.zeros_like(rgb, dtype=np.float32)
    mean = rgb.mean(axis=0, keepdims=True)
    contrast = rng.uniform(0.8, 1.2)
    rgb = (rgb - mean) * contrast + mean
    rgb = rgb * rng.uniform(0.8, 1.2) * rng.uniform(0.92, 1.08, 3) + rng.uniform(-0.05, 0.05, 3)
    if rng.random() < params.colour_cast:
        rgb = rgb * rng.uniform(*params.cast_range, 3)
    if rng.random() < params.exposure:
        rgb = np.clip(rgb, 0, 1) ** rng.uniform(*params.gamma_range)
    rgb = rgb + rng.normal(0, 0.02, rgb.shape)
    if rng.random() < params.grey:
        rgb = np.repeat(rgb.mean(axis=1, keepdims=True), 3, axis=1)
    return np.clip(rgb, 0, 1).astype(np.float32)


def augment(
    xyz: np.ndarray,
    rgb: np.ndarray,
    rng: np.random.Generator,
    params: AugmentParams | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Rotation about z, a mirror half of the time, scaling 0.9-1.1 per axis, a tilt, an elastic
    field for a share of the crops, jitter of a few mm, then :func:`augment_colour`."""
    params = params or AugmentParams()
    theta = rng.uniform(0, 2 * np.pi)
    c, s = np.cos(theta), np.sin(theta)
    centre = xyz.mean(axis=0)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32)
    if params.tilt_degrees > 0:
        rot = tilt_matrix(rng, params.tilt_degrees) @ rot
    scale = rng.uniform(0.9, 1.1, 3)
    if rng.random() < 0.5:
        scale[0] = -scale[0]
    xyz = (xyz - centre) @ rot.T * scale.astype(np.float32) + centre
    if params.elastic and rng.random() < params.elastic:
        xyz = elastic_distortion(xyz, rng)
    xyz = xyz + rng.normal(0, rng.uniform(*params.noise), xyz.shape).astype(np.float32)
    return xyz.astype(np.float32), augment_colour(rgb, rng, params)


def cut_region(
    xyz: np.ndarray, centre: np.ndarray, rng: np.random.Generator, params: AugmentParams
) -> np.ndarray | None:
    """A boolean mask that makes a region partial, or None to keep it whole.

    A vertical plane a little beyond the centre drops one side (a room scanned from one
    corner), or only a band above the lowest point is kept (a slice, as the S3DIS fragment).
    """
    draw = rng.random()
    if draw < params.partial:
        phi = rng.uniform(0, 2 * np.pi)
        normal = np.array([np.cos(phi), np.sin(phi)], dtype=np.float32)
        reach = float(np.abs((xyz[:, :2] - centre[:2]) @ normal).max(initial=0.0))
        offset = rng.uniform(0.1, 0.5) * reach
        return (xyz[:, :2] - centre[:2]) @ normal <= offset
    if draw < params.partial + params.slice:
        floor = float(xyz[:, 2].min(initial=0.0))
        return xyz[:, 2] <= floor + rng.uniform(*params.slice_height)
    return None


def sensor_gaps(
    xyz: np.ndarray,
    labels: np.ndarray,
    centre: np.ndarray,
    rng: np.random.Generator,
    params: AugmentParams,
) -> np.ndarray | None:
    """A boolean mask of what a handheld sensor would have captured of the region, or None for
    all of it: for a share of the crops no ceiling (labelled 0), for a share one to four
    occlusion holes, balls emptied around points of the region's inner third (where the crop
    will be)."""
    keep = np.ones(len(xyz), dtype=bool)
    if rng.random() < params.no_ceiling:
        keep &= labels != CEILING
    if rng.random() < params.holes and len(xyz):
        dist = np.linalg.norm(xyz - centre, axis=1)
        inner = np.flatnonzero(dist <= np.quantile(dist, 1 / 3))
        centres = xyz[rng.choice(inner, size=int(rng.integers(1, 5)))]
        radius = rng.uniform(*params.hole_radius, len(centres))
        for c, r in zip(centres, radius, strict=True):
            keep &= ((xyz - c) ** 2).sum(axis=1) > r * r
    return None if keep.all() else keep


def density_sample(
    xyz: np.ndarray,
    rgb: np.ndarray,
    labels: np.ndarray,
    grid: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid sub-sample at ``grid`` with a random grid offset: one point per cell (the mean, as
    the network's own sub-sampling), colour means and majority labels."""
    shifted = xyz + rng.uniform(0, grid, 3).astype(xyz.dtype)
    inverse, _ = voxel_index(shifted, grid)
    cells = int(inverse.max()) + 1 if len(inverse) else 0
    pts = cell_means(xyz.astype(np.float64), inverse, cells).astype(np.float32)
    colour = cell_means(rgb.astype(np.float64), inverse, cells).astype(np.float32)
    return pts, colour, cell_majority(labels, inverse, cells)


def add_stray_points(
    xyz: np.ndarray,
    rgb: np.ndarray,
    labels: np.ndarray,
    rng: np.random.Generator,
    params: AugmentParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For a share of the crops, replace ``stray_share`` of the points by stray returns 0.5-3 m
    outside the crop's box (unlabelled, -1), so a few wild points do not sway their neighbours'
    labels. The crop keeps its size."""
    n = len(xyz)
    count = int(round(params.stray_share * n))
    if count == 0 or rng.random() >= params.stray:
        return xyz, rgb, labels
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    direction = rng.normal(size=(count, 3))
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-9)
    centre = (lo + hi) / 2
    reach = np.abs(direction) @ ((hi - lo) / 2)  # distance to the box's face along each ray
    far = centre + direction * (reach + rng.uniform(0.5, 3.0, count))[:, None]
    slots = rng.choice(n, size=count, replace=False)
    xyz, rgb, labels = xyz.copy(), rgb.copy(), labels.copy()
    xyz[slots] = far.astype(xyz.dtype)
    rgb[slots] = rng.uniform(0, 1, (count, 3)).astype(rgb.dtype)
    labels[slots] = -1
    return xyz, rgb, labels


class StepAugment(BaseModel):
    """Augmentation drawn per step on bank crops (none changes a neighbour)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    rotate: bool = Field(True, description="rotate each crop by a random angle about z")
    mirror: float = Field(0.5, ge=0, le=1, description="share of crops mirrored in x")
    scale: tuple[float, float] = Field((0.95, 1.05), description="uniform scale range")
    gain: float = Field(0.1, ge=0, le=0.5, description="per-channel colour gain of 1 +- this")
    offset: float = Field(0.03, ge=0, le=0.2, description="per-channel colour offset +- this")
    colour_drop: float = Field(0.05, ge=0, le=1, description="share of crops without colour")
