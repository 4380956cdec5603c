"""The geometric segmentation of §2.2 end to end: align, planes, clusters, colour regions."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from jointseg.exceptions import ConfigError
from jointseg.geometry import alignment, clustering, planes
from jointseg.geometry.params import (
    GeometryParams,
    ResolvedGeometryParams,
    detail_spacing,
    resolve,
)
from jointseg.geometry.structure import read_structure
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
    structure : ndarray of shape (N,), int8, optional
        The structural reading of every point (:mod:`jointseg.geometry.structure`): the floor,
        ceiling or wall class index, -1 for none; None when switched off.
    structure_confidence : ndarray of shape (N,), float32, optional
        How sure that reading is, in [0, 1].
    floor_z, ceiling_z : float, optional
        The storey's floor and ceiling levels the reading found (the scan's z), None where none.
    """

    segments: np.ndarray
    plane_id: np.ndarray
    planes: list[PlaneInfo]
    params: ResolvedGeometryParams
    timings: dict[str, float] = field(default_factory=dict)
    structure: np.ndarray | None = None
    structure_confidence: np.ndarray | None = None
    floor_z: float | None = None
    ceiling_z: float | None = None

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
    diff = clustering.colour_distance(rgb, a, b)
    return float(np.median(diff)) if len(diff) else 0.0


def segment(
    scan: Scan,
    params: GeometryParams | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
    *,
    seed: int = 0,
    resolved: ResolvedGeometryParams | None = None,
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
    resolved : ResolvedGeometryParams, optional
        Every threshold, the spacing and the yaw fixed in advance (:func:`scan_params` on the
        whole scan), so the tiles of a big scan are cut with the same thresholds and frame;
        ``params`` is then ignored. Default: derived from this scan.

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
    laps = _Laps(progress, cancel)
    centre = scan.xyz.mean(axis=0)
    xyz = scan.xyz - centre
    if resolved is None:
        spacing = estimate_spacing(xyz, rng=rng) or 1e-3
    else:
        params, spacing = resolved, resolved.spacing
    laps.lap("spacing", 0.05)
    work = _voxelise(xyz, scan.rgb, params.voxel_factor * detail_spacing(spacing))
    laps.lap("voxels", 0.1)
    yaw = None if resolved is None else resolved.yaw_deg
    frame = _align(work.xyz, max(spacing, work.voxel), align=params.align, yaw=yaw)
    laps.lap("alignment", 0.2)
    graph, colours, p = _neighbours(work, params, n_points=n, spacing=spacing, yaw=frame.yaw)
    if resolved is not None:
        p = resolved
    laps.lap("neighbours", 0.4)
    bounds = planes.robust_bounds(frame.xyz)  # the box faces' and the further planes' own
    found, plane_id = _box_planes(frame.xyz, p, rng, bounds)
    laps.lap("box_planes", 0.5)
    found, plane_id = _further_planes(
        frame, plane_id, found, p, max(spacing, work.voxel), rng, bounds
    )
    laps.lap("further_planes", 0.6)
    groups = _groups(graph, plane_id, len(found), p)
    laps.lap("clustering", 0.7)
    regions = _regions(graph, work, colours, groups, frame.normals, p)
    laps.lap("region_growing", 0.95)
    segments = regions.astype(np.int32)[work.inverse]  # narrowed, then gathered: half the bytes
    point_plane = plane_id.astype(np.int32)[work.inverse]
    laps.lap("map_back", 0.97)
    infos = _plane_infos(found, frame.rotation.T, centre, point_plane)
    log.info("geometry: %d points, %d main planes, %d segments", n, len(found), regions.max() + 1)
    if not p.structure:
        return GeometryResult(segments, point_plane, infos, p, laps.timings)
    found_structure = _structure(work, regions, spacing, float(centre[2]), seed)
    laps.lap("structure", 1.0)
    return GeometryResult(segments, point_plane, infos, p, laps.timings, *found_structure)


def _structure(
    work: _WorkSet, regions: np.ndarray, spacing: float, z0: float, seed: int
) -> tuple[np.ndarray, np.ndarray, float | None, float | None]:
    """The structure reading on the voxel centroids (an even density, a fraction of the
    points), carried to every point: class, confidence, floor and ceiling levels (scan z)."""
    reading = read_structure(work.xyz, regions, max(spacing, work.voxel), seed=seed)
    log.info("geometry: structure %s", reading.counts())
    floor, ceiling = (None if z is None else z + z0 for z in (reading.floor_z, reading.ceiling_z))
    kind = reading.point_kind(regions)[work.inverse]
    return kind, reading.point_confidence(regions)[work.inverse], floor, ceiling


def scan_params(
    scan: Scan,
    params: GeometryParams | None = None,
    *,
    n_points: int | None = None,
    seed: int = 0,
) -> ResolvedGeometryParams:
    """Every adaptive threshold of :func:`segment` derived from ``scan`` without segmenting it.

    A big scan is segmented tile by tile; deriving the spacing, the yaw and the colour noise
    once, from a contiguous part of it, and handing the result to every tile
    (``segment(..., resolved=...)``) cuts all tiles with the same thresholds and frame.

    Parameters
    ----------
    scan : Scan
        A contiguous part of the scan (a few hundred thousand points or more), not a random
        sample: the spacing is the distance between neighbouring points.
    params : GeometryParams, optional
    n_points : int, optional
        Points in the whole scan (sets ``min_region_points``); default ``len(scan)``.
    seed : int

    Raises
    ------
    ConfigError
        When the scan has too few points.
    """
    params = params or GeometryParams()
    if len(scan) < 10:
        raise ConfigError(f"geometry needs at least 10 points, got {len(scan)}")
    rng = np.random.default_rng(seed)
    xyz = scan.xyz - scan.xyz.mean(axis=0)
    spacing = estimate_spacing(xyz, rng=rng) or 1e-3
    work = _voxelise(xyz, scan.rgb, params.voxel_factor * detail_spacing(spacing))
    frame = _align(work.xyz, max(spacing, work.voxel), align=params.align)
    n = len(scan) if n_points is None else n_points
    return _neighbours(work, params, n_points=n, spacing=spacing, yaw=frame.yaw)[2]


class _Laps:
    """Times each step of :func:`segment`, reports progress and checks for cancellation
    between steps (the keys of ``GeometryResult.timings``)."""

    def __init__(self, progress: ProgressFn | None, cancel: CancelToken | None) -> None:
        self.progress = progress
        self.cancel = cancel
        self.timings: dict[str, float] = {}
        self._clock = time.perf_counter()

    def lap(self, name: str, fraction: float) -> None:
        """Record the time since the last lap as ``name``, report ``fraction`` done."""
        now = time.perf_counter()
        self.timings[name] = now - self._clock
        self._clock = now
        report(self.progress, STAGE, fraction)
        check_cancel(self.cancel)


@dataclass(frozen=True)
class _WorkSet:
    """The points every step works on (voxel centroids, or the scan itself) and the way back.

    ``inverse`` maps scan points to work points, ``weights`` counts the scan points each work
    point stands for, ``tree`` indexes ``xyz``.
    """

    xyz: np.ndarray
    rgb: np.ndarray | None
    inverse: np.ndarray
    weights: np.ndarray
    voxel: float
    tree: cKDTree


def _voxelise(xyz: np.ndarray, rgb: np.ndarray | None, voxel: float) -> _WorkSet:
    """Voxel centroids (and mean colours) to work on: a few points per voxel carry no extra
    geometry, and every later step then costs a fraction of the per-point version."""
    n = len(xyz)
    if voxel > 0:
        inverse, work = voxel_index(xyz, voxel)
        weights = np.bincount(inverse).astype(np.float64)
        # 8-bit colour sums as its float32 copy would (bincount adds in float64 either way)
        values = None if rgb is None else rgb if rgb.dtype == np.uint8 else rgb.astype(np.float32)
        work_rgb = (
            None if values is None else cell_means(values, inverse, len(work)).astype(np.float32)
        )
    else:
        inverse, work, weights = np.arange(n), xyz, np.ones(n)
        work_rgb = None if rgb is None else rgb.astype(np.float32)
    return _WorkSet(work, work_rgb, inverse, weights, voxel, cKDTree(work))


@dataclass(frozen=True)
class _Frame:
    """Work points and normals rotated so the dominant walls are the x and y axes."""

    xyz: np.ndarray
    normals: np.ndarray
    yaw: float
    rotation: np.ndarray


def _align(work: np.ndarray, spacing: float, *, align: bool, yaw: float | None = None) -> _Frame:
    """Normals and the yaw rotation (``yaw`` when given, else the dominant walls'), so the
    box-face planes can be searched axis-aligned."""
    normals = alignment.point_normals(work, spacing, max_voxels=100_000)
    if yaw is None:
        yaw = alignment.dominant_yaw(normals) if align else 0.0
    rot = alignment.rotation_z(-yaw)
    return _Frame(work @ rot.T, normals @ rot.T, yaw, rot)


def _neighbours(
    work: _WorkSet, params: GeometryParams, *, n_points: int, spacing: float, yaw: float
) -> tuple[clustering.NeighbourGraph, np.ndarray | None, ResolvedGeometryParams]:
    """The shared neighbour graph, the (smoothed) colours and the thresholds resolved with the
    colour noise they reveal."""
    provisional = resolve(
        params, n_points=n_points, spacing=spacing, colour_noise=None, yaw_deg=yaw
    )
    radius = max(provisional.cluster_distance, 1.5 * work.voxel) * 4
    graph = clustering.neighbour_graph(work.tree, work.xyz, k=params.neighbours, radius=radius)
    colours = work.rgb
    if colours is not None and params.colour_smoothing:
        near = graph.within(provisional.cluster_distance, adaptive=params.adaptive_radius)
        colours = clustering.smooth_colours(graph, colours, near)
    noise = colour_noise(graph, colours) if colours is not None else None
    p = resolve(params, n_points=n_points, spacing=spacing, colour_noise=noise, yaw_deg=yaw)
    return graph, colours, p


def _box_planes(
    aligned: np.ndarray,
    p: ResolvedGeometryParams,
    rng: np.random.Generator,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[list[tuple[planes.Plane, np.ndarray]], np.ndarray]:
    """The bounding-box face planes (floor, ceiling, four walls) of the aligned work points,
    and the plane id of every work point (-1 off them); ``bounds``: their robust bounds."""
    found = planes.box_face_planes(
        aligned,
        face_distance=p.face_distance,
        plane_distance=p.plane_distance,
        iterations=p.ransac_iterations,
        sample=p.ransac_sample,
        max_tilt_deg=p.max_plane_tilt_deg,
        min_points=p.min_face_points,
        rng=rng,
        bounds=bounds,
    )
    return found, _assign_planes(aligned, found, len(aligned))


def _further_planes(
    frame: _Frame,
    plane_id: np.ndarray,
    found: list[tuple[planes.Plane, np.ndarray]],
    p: ResolvedGeometryParams,
    spacing: float,
    rng: np.random.Generator,
    bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[list[tuple[planes.Plane, np.ndarray]], np.ndarray]:
    """Walls and floors beyond the box faces, then points leaning off their plane released:
    all main planes and the plane id of every work point (``bounds``: the work points'
    robust bounds, when known)."""
    found, plane_id = list(found), plane_id.copy()
    if p.extra_planes:
        lo, hi = planes.robust_bounds(frame.xyz) if bounds is None else bounds
        extra = planes.further_planes(
            frame.xyz,
            frame.normals,
            np.flatnonzero(plane_id < 0),
            plane_distance=p.plane_distance,
            spacing=spacing,
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
        plane_id = _release_off_plane(plane_id, found, frame.normals, p.plane_normal_deg)
    return found, plane_id


def _groups(
    graph: clustering.NeighbourGraph,
    plane_id: np.ndarray,
    n_planes: int,
    p: ResolvedGeometryParams,
) -> np.ndarray:
    """Main planes first, then Euclidean clusters of the rest, so region growing never crosses
    from one to another: the group of every work point."""
    clusters = clustering.euclidean_clusters(
        graph, plane_id < 0, tolerance=p.cluster_distance, adaptive=p.adaptive_radius
    )
    return np.where(plane_id >= 0, plane_id, n_planes + clusters)


def _regions(
    graph: clustering.NeighbourGraph,
    work: _WorkSet,
    colours: np.ndarray | None,
    groups: np.ndarray,
    normals: np.ndarray,
    p: ResolvedGeometryParams,
) -> np.ndarray:
    """Colour regions inside each plane or cluster, small ones merged: the segment of every
    work point."""
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
    return clustering.merge_small_regions(
        graph,
        work.xyz,
        regions,
        groups,
        work.weights,
        min_points=p.min_region_points,
        tree=work.tree,
    )


def _plane_infos(
    found: list[tuple[planes.Plane, np.ndarray]],
    inverse_rot: np.ndarray,
    centre: np.ndarray,
    point_plane: np.ndarray,
) -> list[PlaneInfo]:
    """The main planes back in the scan's own frame (un-rotated, un-centred), with point counts."""
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
    return infos


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
