"""The geometric segmentation of §2.2 end to end: align, planes, clusters, colour regions."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from jointseg.exceptions import ConfigError
from jointseg.geometry import alignment, clustering, planes
from jointseg.geometry.params import GeometryParams, ResolvedGeometryParams, resolve
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan
from jointseg.spacing import estimate_spacing
from jointseg.voxels import cell_means, voxel_index

log = logging.getLogger(__name__)
STAGE = "geometry"


@dataclass(frozen=True)
class PlaneInfo:
    """A main plane in the scan's own frame: n . p + offset = 0, its kind and point count."""

    normal: tuple[float, float, float]
    offset: float
    kind: str
    name: str
    points: int


@dataclass(frozen=True)
class GeometryResult:
    """Segment id for every point, which points lie on main planes, and how long each step took.

    Attributes
    ----------
    segments : ndarray of shape (N,), int32
        Segment id 0..S-1 of every point.
    plane_id : ndarray of shape (N,), int32
        Index into ``planes`` of the main plane a point belongs to, -1 for the rest.
    """

    segments: np.ndarray
    plane_id: np.ndarray
    planes: list[PlaneInfo]
    params: ResolvedGeometryParams
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def main_plane(self) -> np.ndarray:
        """Boolean mask of main-plane points."""
        return self.plane_id >= 0

    @property
    def plane_segments(self) -> np.ndarray:
        """Boolean array over segment ids: true where most of the segment lies on a main plane."""
        on_plane = np.bincount(self.segments, weights=self.main_plane, minlength=self.n_segments)
        return on_plane > 0.5 * np.bincount(self.segments, minlength=self.n_segments)

    @property
    def n_segments(self) -> int:
        """Number of segments."""
        return int(self.segments.max()) + 1 if len(self.segments) else 0


def colour_noise(graph: clustering.NeighbourGraph, rgb: np.ndarray, sample: int = 200_000) -> float:
    """Median colour distance (RGB units) between neighbouring points: the scan's colour noise."""
    nearest = np.flatnonzero(np.r_[True, graph.src[1:] != graph.src[:-1]])
    if len(nearest) > sample:
        nearest = nearest[:: len(nearest) // sample]
    a, b = graph.src[nearest], graph.dst[nearest]
    diff = np.linalg.norm(rgb[a] - rgb[b], axis=1)
    return float(np.median(diff)) if len(diff) else 0.0


def segment(
    scan: Scan,
    params: GeometryParams | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
    *,
    seed: int = 0,
) -> GeometryResult:
    """Split a scan into geometric segments without semantics (§2.2 of the paper).

    Parameters
    ----------
    scan : Scan
        Points (metres) with optional colour; z must point up.
    params : GeometryParams, optional
        Thresholds; unset ones are derived from the scan's spacing and colour noise.
    progress : callable, optional
        ``progress("geometry", fraction)``.
    cancel : object with ``is_set()``, optional
        Checked between steps.
    seed : int
        RANSAC randomness; the result is deterministic for a seed.

    Returns
    -------
    GeometryResult

    Raises
    ------
    ConfigError
        When the scan has too few points to segment.
    """
    params = params or GeometryParams()
    n = len(scan)
    if n < 10:
        raise ConfigError(f"geometry needs at least 10 points, the scan has {n}")
    rng = np.random.default_rng(seed)
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str, fraction: float) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = now - clock
        clock = now
        report(progress, STAGE, fraction)
        check_cancel(cancel)

    centre = scan.xyz.mean(axis=0)
    xyz = scan.xyz - centre
    spacing = estimate_spacing(xyz, rng=rng) or 1e-3
    lap("spacing", 0.05)

    # Work on voxel centroids: a few points per voxel carry no extra geometry, and every
    # later step then costs a fraction of the per-point version. Labels map back per voxel.
    voxel = params.voxel_factor * spacing
    if voxel > 0:
        inverse, work = voxel_index(xyz, voxel)
        weights = np.bincount(inverse).astype(np.float64)
        work_rgb = (
            None
            if scan.rgb is None
            else cell_means(scan.rgb.astype(np.float32), inverse, len(work)).astype(np.float32)
        )
    else:
        inverse, work, weights = np.arange(n), xyz, np.ones(n)
        work_rgb = None if scan.rgb is None else scan.rgb.astype(np.float32)
    tree = cKDTree(work)
    lap("voxels", 0.1)

    normals = alignment.point_normals(work, max(spacing, voxel), max_voxels=100_000)
    yaw = alignment.dominant_yaw(normals) if params.align else 0.0
    rot = alignment.rotation_z(-yaw)
    aligned = work @ rot.T
    normals = normals @ rot.T
    lap("alignment", 0.2)

    provisional = resolve(params, n_points=n, spacing=spacing, colour_noise=None, yaw_deg=yaw)
    radius = max(provisional.cluster_distance, 1.5 * voxel) * 4
    graph = clustering.neighbour_graph(tree, work, k=params.neighbours, radius=radius)
    colours = work_rgb
    if colours is not None and params.colour_smoothing:
        near = graph.within(provisional.cluster_distance, adaptive=params.adaptive_radius)
        colours = clustering.smooth_colours(graph, colours, near)
    noise = colour_noise(graph, colours) if colours is not None else None
    p = resolve(params, n_points=n, spacing=spacing, colour_noise=noise, yaw_deg=yaw)
    lap("neighbours", 0.4)

    found = planes.box_face_planes(
        aligned,
        face_distance=p.face_distance,
        plane_distance=p.plane_distance,
        iterations=p.ransac_iterations,
        sample=p.ransac_sample,
        max_tilt_deg=p.max_plane_tilt_deg,
        min_points=p.min_face_points,
        rng=rng,
    )
    plane_id = _assign_planes(aligned, found, len(work))
    lap("box_planes", 0.5)

    if p.extra_planes:
        lo, hi = planes.robust_bounds(aligned)
        extra = planes.further_planes(
            aligned,
            normals,
            np.flatnonzero(plane_id < 0),
            plane_distance=p.plane_distance,
            spacing=max(spacing, voxel),
            room_height=float(hi[2] - lo[2]),
            min_wall_area=p.min_wall_area,
            min_wall_height_ratio=p.min_wall_height_ratio,
            min_floor_area=p.min_floor_area,
            min_fill=p.min_plane_fill,
            rng=rng,
        )
        for plane, idx in extra:
            plane_id[idx] = len(found)
            found.append((plane, idx))
    if p.plane_normal_deg < 90:
        plane_id = _release_off_plane(plane_id, found, normals, p.plane_normal_deg)
    lap("further_planes", 0.6)

    clusters = clustering.euclidean_clusters(
        graph, plane_id < 0, tolerance=p.cluster_distance, adaptive=p.adaptive_radius
    )
    # groups: main planes first, then clusters, so region growing never crosses them
    groups = np.where(plane_id >= 0, plane_id, len(found) + clusters)
    lap("clustering", 0.7)

    regions = clustering.region_grow_rgb(
        graph,
        colours,
        groups,
        distance=p.cluster_distance,
        point_threshold=p.point_colour_threshold,
        region_threshold=p.region_colour_threshold,
        adaptive=p.adaptive_radius,
        normals=normals,
        max_normal_deg=p.region_normal_deg,
    )
    regions = clustering.merge_small_regions(
        graph, work, regions, groups, weights, min_points=p.min_region_points
    )
    lap("region_growing", 0.95)

    segments = regions[inverse].astype(np.int32)
    point_plane = plane_id[inverse].astype(np.int32)
    lap("map_back", 1.0)
    inverse_rot = rot.T
    infos = []
    for i, (plane, _) in enumerate(found):
        normal = inverse_rot @ plane.normal
        offset = plane.offset - float(normal @ centre)
        infos.append(
            PlaneInfo(
                (float(normal[0]), float(normal[1]), float(normal[2])),
                offset,
                plane.kind,
                plane.name,
                int(np.sum(point_plane == i)),
            )
        )
    log.info("geometry: %d points, %d main planes, %d segments", n, len(found), regions.max() + 1)
    return GeometryResult(
        segments=segments,
        plane_id=point_plane,
        planes=infos,
        params=p,
        timings=timings,
    )


def _release_off_plane(
    plane_id: np.ndarray,
    found: list[tuple[planes.Plane, np.ndarray]],
    normals: np.ndarray,
    max_deg: float,
) -> np.ndarray:
    """Main-plane points whose own normal leans more than ``max_deg`` from their plane's leave
    it: chair legs on the floor, lamps under the ceiling, frames and shelves on a wall are
    near their plane but not of it, and go to the clustering instead."""
    on = np.flatnonzero(plane_id >= 0)
    if len(on) == 0:
        return plane_id
    plane_normals = np.array([plane.normal for plane, _ in found])
    cos = np.abs(np.einsum("ij,ij->i", normals[on], plane_normals[plane_id[on]]))
    out = plane_id.copy()
    out[on[cos < np.cos(np.radians(max_deg))]] = -1
    return out


def _assign_planes(
    xyz: np.ndarray, found: list[tuple[planes.Plane, np.ndarray]], n: int
) -> np.ndarray:
    """Plane index per point; a point in several face sets goes to the nearest plane."""
    plane_id = np.full(n, -1, dtype=np.int64)
    best = np.full(n, np.inf)
    for i, (plane, idx) in enumerate(found):
        d = np.abs(xyz[idx] @ plane.normal + plane.offset)
        closer = d < best[idx]
        plane_id[idx[closer]] = i
        best[idx[closer]] = d[closer]
    return plane_id
