"""Multi-level plane extraction (§2.2.1): bounding-box faces, RANSAC per face, further planes.

All functions work in the yaw-aligned frame, where walls are (close to) x = c or y = c planes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from jointseg.boxes import in_box

FACE_NAMES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")


@dataclass(frozen=True)
class Plane:
    """A main plane: unit ``normal`` and ``offset`` with normal . p + offset = 0 (metres)."""

    normal: np.ndarray
    offset: float
    kind: str  # "box_face", "wall" or "horizontal"
    name: str


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through ``points``: the smallest principal axis is the normal."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[-1]
    return normal, float(-normal @ centre)


def ransac_plane(
    points: np.ndarray,
    *,
    iterations: int,
    threshold: float,
    sample: int,
    rng: np.random.Generator,
    axis: np.ndarray | None = None,
    max_tilt_deg: float = 90.0,
) -> tuple[np.ndarray, float, np.ndarray] | None:
    """RANSAC plane (the paper's fine extraction), scored on a sample, then refined.

    ``iterations`` random triples give candidate planes; each is scored by its inlier count
    (distance < ``threshold``) on a random subset of ``sample`` points, all candidates at once
    in one matrix product. The best is refitted by least squares on its inliers among all
    points. Candidates tilted more than ``max_tilt_deg`` from ``axis`` are discarded.

    Returns
    -------
    (normal, offset, inliers) or None
        ``inliers`` is a boolean mask over ``points``; None when no candidate qualifies.
    """
    m = len(points)
    if m < 3:
        return None
    triples = rng.integers(0, m, size=(iterations, 3))
    p0, p1, p2 = points[triples[:, 0]], points[triples[:, 1]], points[triples[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-12
    normals = normals[ok] / length[ok, None]
    p0 = p0[ok]
    if axis is not None:
        cos_tilt = np.abs(normals @ axis)
        keep = cos_tilt >= np.cos(np.radians(max_tilt_deg))
        normals, p0 = normals[keep], p0[keep]
    if len(normals) == 0:
        return None
    offsets = -np.einsum("ij,ij->i", normals, p0)
    subset = points[rng.choice(m, size=min(sample, m), replace=False)]
    distance = subset @ normals.T
    distance += offsets
    scores = np.count_nonzero(np.abs(distance, out=distance) < threshold, axis=0)
    best = int(np.argmax(scores))
    normal, offset = normals[best], offsets[best]
    for _ in range(2):  # refine: refit on inliers, recompute inliers
        inliers = np.abs(points @ normal + offset) < threshold
        if inliers.sum() < 3:
            break
        normal, offset = fit_plane(points[inliers])
    inliers = np.abs(points @ normal + offset) < threshold
    return normal, float(offset), inliers


def robust_bounds(xyz: np.ndarray, quantile: float = 0.001) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box from low and high quantiles, so a few stray points do not move the faces."""
    lo, hi = np.quantile(xyz, [quantile, 1.0 - quantile], axis=0)  # one partition for both
    return lo, hi


def _densest_layer(
    coord: np.ndarray, value: float, *, inward: float, depth: float, bin_width: float
) -> float:
    """Move a box face to the densest thin layer within ``depth`` inside it.

    Windows set into a wall, doors opened outwards or stray points put the bounding box a few
    centimetres to decimetres outside the wall itself; the wall is the densest layer near the
    face, so the face set is centred there instead.
    """
    inside = inward * (coord - value)
    near = coord[(inside >= -bin_width) & (inside <= depth)]
    if len(near) == 0:
        return value
    bins = max(1, int(np.ceil((depth + bin_width) / bin_width)))
    start = value - bin_width if inward > 0 else value - depth
    hist, edges = np.histogram(near, bins=bins, range=(start, start + bins * bin_width))
    i = int(np.argmax(hist))
    return float(0.5 * (edges[i] + edges[i + 1]))


def box_face_planes(
    xyz: np.ndarray,
    *,
    face_distance: float,
    plane_distance: float,
    iterations: int,
    sample: int,
    max_tilt_deg: float,
    min_points: int,
    rng: np.random.Generator,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[tuple[Plane, np.ndarray]]:
    """Coarse then fine extraction: each bounding-box face's point set (eq. 3-4), RANSAC on it.

    ``bounds`` is :func:`robust_bounds` of ``xyz`` when the caller has it already.

    Returns
    -------
    list of (Plane, indices)
        The main plane of every face that has one, with the indices of its inliers.
    """
    lo, hi = robust_bounds(xyz) if bounds is None else bounds
    found: list[tuple[Plane, np.ndarray]] = []
    for f, name in enumerate(FACE_NAMES):
        axis_i = f // 2
        value = lo[axis_i] if f % 2 == 0 else hi[axis_i]
        value = _densest_layer(
            xyz[:, axis_i],
            value,
            inward=1.0 if f % 2 == 0 else -1.0,
            depth=max(0.5, 4 * face_distance),
            bin_width=plane_distance,
        )
        face_set = np.flatnonzero(np.abs(xyz[:, axis_i] - value) < face_distance)
        if len(face_set) < min_points:
            continue
        axis = np.eye(3)[axis_i]
        fit = ransac_plane(
            xyz[face_set],
            iterations=iterations,
            threshold=plane_distance,
            sample=sample,
            rng=rng,
            axis=axis,
            max_tilt_deg=max_tilt_deg,
        )
        if fit is None or fit[2].sum() < min_points:
            continue
        normal, offset, inliers = fit
        found.append((Plane(normal, offset, "box_face", name), face_set[inliers]))
    return found


def _peaks(values: np.ndarray, *, bin_width: float, min_count: int) -> list[float]:
    """Positions of histogram peaks of ``values`` holding at least ``min_count`` values."""
    if len(values) < min_count:
        return []
    lo, hi = values.min(), values.max()
    bins = max(1, int(np.ceil((hi - lo) / bin_width)) + 1)
    hist, edges = np.histogram(values, bins=bins, range=(lo, lo + bins * bin_width))
    # maxima of the raw histogram (smoothing would fuse the two faces of a thin wall), counted
    # with their neighbours so a plane split across two bins still qualifies
    window = hist + np.concatenate([[0], hist[:-1]]) + np.concatenate([hist[1:], [0]])
    is_peak = (hist >= np.concatenate([[0], hist[:-1]])) & (hist > np.concatenate([hist[1:], [0]]))
    idx = np.flatnonzero(is_peak & (window >= min_count))
    order = idx[np.argsort(-window[idx])]
    return [float(0.5 * (edges[i] + edges[i + 1])) for i in order]


def _patches(uv: np.ndarray, cell: float) -> list[tuple[np.ndarray, float, float, float]]:
    """Split in-plane coordinates into 8-connected patches of occupied ``cell``-sized cells.

    Returns (point indices, area m^2, fill ratio, extent along v) per patch.
    """
    ij = np.floor((uv - uv.min(axis=0)) / cell).astype(np.int64)
    shape = tuple(ij.max(axis=0) + 1)
    grid = np.zeros(shape, dtype=bool)
    grid[ij[:, 0], ij[:, 1]] = True
    labelled, count = ndimage.label(grid, structure=np.ones((3, 3), dtype=bool))
    point_patch = labelled[ij[:, 0], ij[:, 1]] - 1
    out = []
    slices = ndimage.find_objects(labelled)
    order = np.argsort(point_patch, kind="stable")
    bounds = np.searchsorted(point_patch[order], np.arange(count + 1))
    for p in range(count):
        sl = slices[p]
        cells = int((labelled[sl] == p + 1).sum())
        box = (sl[0].stop - sl[0].start) * (sl[1].stop - sl[1].start)
        members = order[bounds[p] : bounds[p + 1]]
        out.append((members, cells * cell * cell, cells / box, (sl[1].stop - sl[1].start) * cell))
    return out


def further_planes(
    xyz: np.ndarray,
    normals: np.ndarray,
    candidates: np.ndarray,
    *,
    plane_distance: float,
    spacing: float,
    room_height: float,
    min_wall_area: float,
    min_wall_height_ratio: float,
    min_floor_area: float,
    min_fill: float,
    rng: np.random.Generator,
) -> list[tuple[Plane, np.ndarray]]:
    """Large axis-aligned planes among ``candidates`` beyond the box faces (L rooms, floors).

    Points whose normal is within 20 degrees of an axis vote in a histogram of their
    coordinate along it; each peak's band is split into connected patches, and a patch
    becomes a main plane when it is large, dense and (for walls) spans most of the room height.
    """
    found: list[tuple[Plane, np.ndarray]] = []
    taken = np.zeros(len(xyz), dtype=bool)
    cos20 = np.cos(np.radians(20.0))
    cell = max(8.0 * spacing, 0.2)
    for axis_i in (0, 1, 2):
        vertical = axis_i < 2
        min_area = min_wall_area if vertical else min_floor_area
        aligned = candidates[np.abs(normals[candidates, axis_i]) > cos20]
        coord = xyz[aligned, axis_i]  # gathered once for all of the axis's peaks
        min_count = int(min_area * min_fill / max(spacing, 1e-3) ** 2 * 0.25)
        other = [a for a in range(3) if a != axis_i]
        kind = "wall" if vertical else "horizontal"
        for c in _peaks(coord, bin_width=plane_distance, min_count=min_count):
            # A long wall under a small residual yaw spans more than one bin, and the two faces
            # of a thin wall can share a peak: fit planes in a wider band, a few in turn.
            wide = aligned[(np.abs(coord - c) < 3 * plane_distance) & ~taken[aligned]]
            for _ in range(3):
                if len(wide) < min_count:
                    break
                fit = ransac_plane(
                    xyz[wide],
                    iterations=200,
                    threshold=plane_distance,
                    sample=2000,
                    rng=rng,
                    axis=np.eye(3)[axis_i],
                    max_tilt_deg=5.0,
                )
                if fit is None or fit[2].sum() < 3:
                    break
                band = wide[fit[2]]
                wide = wide[~fit[2]]
                for members, area, fill, v_extent in _patches(xyz[band][:, other], cell):
                    if area < min_area or fill < min_fill:
                        continue
                    if vertical and v_extent < min_wall_height_ratio * room_height:
                        continue
                    pts = _plane_region(
                        xyz,
                        candidates[~taken[candidates]],
                        band[members],
                        plane_distance=plane_distance,
                        margin=cell,
                    )
                    if len(pts) < 3:  # the seeds' own plane holds none of the free points
                        continue
                    taken[pts] = True
                    plane = Plane(*fit_plane(xyz[pts]), kind, f"{kind}_{len(found)}")
                    found.append((plane, pts))
    return found


def _plane_region(
    xyz: np.ndarray, free: np.ndarray, seeds: np.ndarray, *, plane_distance: float, margin: float
) -> np.ndarray:
    """All free points near the plane through ``seeds`` and inside their box plus ``margin``:
    the whole patch, not only the points whose normals voted for it."""
    normal, offset = fit_plane(xyz[seeds])
    near = free[np.abs(xyz[free] @ normal + offset) < plane_distance]
    lo, hi = xyz[seeds].min(axis=0) - margin, xyz[seeds].max(axis=0) + margin
    return near[in_box(xyz[near], lo, hi)]
