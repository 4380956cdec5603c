"""A finished job's result as the viewer's panels: positions, colours and label groups.

Everything here is arrays in, arrays out, so it is tested without a browser. A result file is
what ``jointseg segment`` writes (``network_label``, ``segment``, ``fused_label``, ... next to
xyz, colour and, for labelled input, the ground truth ``label``).
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.classes import NUM_CLASSES, UNLABELLED, colourise
from jointseg.grouping import cell_keys
from jointseg.lru import LRUCache
from jointseg.spacing import estimate_spacing
from web.result_reader import read_sample

log = logging.getLogger(__name__)

#: Most points one panel shows; the full resolution stays in the downloads.
MAX_PANEL_POINTS = 2_000_000
#: Rows sampled from a big file per point a panel may show, before the voxel thinning evens
#: out their density.
CANDIDATES_PER_POINT = 2
#: The quantiles of each axis that bound the room the views frame, and the margin added on each
#: side (a share of their span, never beyond the points): stray points (a reflection, a point
#: seen through a window 100 m away) are left out of every fit, a room's own walls are not.
ROBUST_QUANTILES = (0.01, 0.99)
ROBUST_MARGIN = 0.1
#: Points the quantiles are read from (an even sample of larger scans).
ROBUST_SAMPLE = 200_000


@dataclass(frozen=True)
class Panel:
    """One copy of the scan in the scene: what colours it and which label hides its points."""

    key: str
    title: str


RAW = Panel("raw", "Raw RGB")
NETWORK = Panel("network", "Network labels")
FUSED = Panel("fused", "Fused labels")
TRUTH = Panel("truth", "Ground truth")
SEGMENTS = Panel("segments", "Segments")
CONFIDENCE = Panel("confidence", "Confidence")
ERRORS = Panel("errors", "Errors")
#: Left-to-right order of the panels in the scene.
PANELS: tuple[Panel, ...] = (RAW, NETWORK, FUSED, TRUTH, SEGMENTS, CONFIDENCE, ERRORS)
#: Error map colours: fused label right, wrong, and no ground truth at the point.
RIGHT_COLOUR = (150, 150, 150)
WRONG_COLOUR = (214, 39, 40)
NO_TRUTH_COLOUR = (225, 225, 225)
#: Confidence ramp from 0 to 1: red, yellow, green (ColorBrewer RdYlGn ends and middle).
CONFIDENCE_RAMP = np.array([[215, 48, 39], [254, 224, 139], [26, 152, 80]], dtype=np.float64)


@dataclass(frozen=True, eq=False)
class SceneData:
    """A result file reduced to what the viewer draws.

    Attributes
    ----------
    xyz : ndarray of shape (M, 3), float32, metres
        Shown points, centred on the scan's bounding-box centre (float32 keeps millimetres
        within kilometres of the centre; viser's default float16 would not).
    centre : ndarray of shape (3,), float64
        What was subtracted: the centre of the room's robust box (:func:`robust_box`).
    extent : ndarray of shape (3,), float64, metres
        Size of the room's robust box (:func:`robust_box`: the bounding box of a scan without
        stray points), so that the panels' layout and every camera fit leave stray points out.
    rgb : ndarray of shape (M, 3), uint8
        Scan colour (grey when the scan had none).
    network, fused : ndarray of shape (M,), int32
        Labels of the shown points.
    truth : ndarray of shape (M,), int32, optional
        Ground truth when the scan had one.
    segments : ndarray of shape (M,), int32
    changed : ndarray of shape (M,), bool
        Points whose label the fusion changed.
    total_points : int
        Points in the result file (M <= total_points).
    voxel : float or None, metres
        Cell size of the voxel down-sampling, None when every point is shown.
    spacing : float, metres
        Median point spacing of the shown points (a good default point size).
    counts : dict of str to ndarray of shape (NUM_CLASSES + 1,), int64
        Full-resolution points per class for ``network``, ``fused`` and ``truth``; the last
        entry counts unlabelled points.
    report : dict or None
        The job's report.json.
    confidence : ndarray of shape (M,), float32, optional
        The network's confidence in its label, when the result has it.
    instance : ndarray of shape (M,), int32, optional
        The object of each shown point (-1: none), when the result has it.
    rows : ndarray of shape (M,), int64, optional
        The file's row of each shown point, ascending (label edits map the file's points to
        the shown ones through it); None: every row, in order.
    to_work : ndarray of shape (4, 4), optional
        The frame stage's transform from the file's coordinates to the levelled metric frame
        the points are shown in (None: shown as stored); picking maps back through it.
    """

    xyz: np.ndarray
    centre: np.ndarray
    extent: np.ndarray
    rgb: np.ndarray
    network: np.ndarray
    fused: np.ndarray
    truth: np.ndarray | None
    segments: np.ndarray
    changed: np.ndarray
    total_points: int
    voxel: float | None
    spacing: float
    counts: dict[str, np.ndarray]
    report: dict[str, Any] | None
    confidence: np.ndarray | None = None
    to_work: np.ndarray | None = None
    instance: np.ndarray | None = None
    rows: np.ndarray | None = None

    def shown_xyz(self, user: np.ndarray) -> np.ndarray:
        """Points in the file's own coordinates ((..., 3)) as shown: levelled, centred."""
        p = np.asarray(user, dtype=np.float64)
        if self.to_work is not None:
            p = p @ self.to_work[:3, :3].T + self.to_work[:3, 3]
        return p - self.centre

    @property
    def panels(self) -> tuple[Panel, ...]:
        """The panels this result can show (ground truth and the error map only when it has a
        ground truth, confidence only when it has the network's confidence)."""
        out = []
        for p in PANELS:
            if p in (TRUTH, ERRORS) and self.truth is None:
                continue
            if p is CONFIDENCE and self.confidence is None:
                continue
            out.append(p)
        return tuple(out)

    def file_xyz(self, shown: np.ndarray) -> np.ndarray:
        """Shown positions (scene coordinates, (..., 3)) back in the file's own coordinates."""
        work = np.asarray(shown, dtype=np.float64) + self.centre
        if self.to_work is None:
            return work
        m = self.to_work
        return np.linalg.solve(m[:3, :3], (work - m[:3, 3]).T).T

    @property
    def nbytes(self) -> int:
        """Memory held by the arrays, bytes."""
        arrays = [self.xyz, self.rgb, self.network, self.fused, self.segments, self.changed]
        if self.truth is not None:
            arrays.append(self.truth)
        return sum(a.nbytes for a in arrays)

    def labels_of(self, panel: Panel) -> np.ndarray:
        """The label that decides whether a point of ``panel`` is hidden with its class.

        Label panels use their own labels; the raw and segment panels follow the fused labels,
        the result.
        """
        if panel in (NETWORK, CONFIDENCE):
            return self.network
        if panel is TRUTH and self.truth is not None:
            return self.truth
        return self.fused

    def colours_of(self, panel: Panel) -> np.ndarray:
        """Colours of ``panel``'s points, (M, 3) uint8: scan colour, class palette, or a random
        colour per segment."""
        if panel is RAW:
            return self.rgb
        if panel is SEGMENTS:
            return segment_colours(self.segments)
        if panel is CONFIDENCE and self.confidence is not None:
            return confidence_colours(self.confidence)
        if panel is ERRORS and self.truth is not None:
            return error_colours(self.fused, self.truth)
        return colourise(self.labels_of(panel))


def confidence_colours(confidence: np.ndarray) -> np.ndarray:
    """(N, 3) uint8 along :data:`CONFIDENCE_RAMP`: red at 0, yellow at 0.5, green at 1."""
    t = np.clip(np.nan_to_num(confidence.astype(np.float64)), 0.0, 1.0) * 2.0
    low = np.minimum(t.astype(np.int64), 1)
    frac = (t - low)[:, None]
    rgb = CONFIDENCE_RAMP[low] * (1.0 - frac) + CONFIDENCE_RAMP[low + 1] * frac
    return np.round(rgb).astype(np.uint8)


def error_colours(fused: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(N, 3) uint8: grey where the fused label equals the ground truth, red where it does not,
    pale where the point has no ground truth."""
    out = np.empty((fused.shape[0], 3), dtype=np.uint8)
    out[:] = RIGHT_COLOUR
    out[fused != truth] = WRONG_COLOUR
    out[truth < 0] = NO_TRUTH_COLOUR
    return out


def voxel_downsample(xyz: np.ndarray, max_points: int) -> tuple[np.ndarray, float | None]:
    """Keep one point per cubic cell, with the cell grown until at most ``max_points`` remain.

    The first point of each cell is kept (not a centroid), so every panel shows the same real
    points with their own labels.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), metres
    max_points : int
        At least 1.

    Returns
    -------
    index : ndarray of shape (M,), int64
        Kept points in ascending order, M <= max_points.
    voxel : float or None
        The cell size used, None when N <= max_points (everything kept).
    """
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    n = xyz.shape[0]
    if n <= max_points:
        return np.arange(n, dtype=np.int64), None
    lo, _ = axis_bounds(xyz)
    low, high = robust_box(xyz)  # a stray point far away would make the first guess coarse
    span = np.maximum(high - low, 1e-6)
    # a scan is mostly surfaces: start from the bounding box's surface area per point
    area = 2.0 * (span[0] * span[1] + span[0] * span[2] + span[1] * span[2])
    voxel = math.sqrt(area / max_points)
    for _ in range(32):
        first = first_in_cells(xyz, lo, voxel)
        if first.size <= max_points:
            return first, float(voxel)
        # occupied cells scale about as 1 / voxel^2 on surfaces
        voxel *= max(math.sqrt(first.size / max_points), 1.0) * 1.02
    raise RuntimeError("voxel down-sampling did not converge")  # pragma: no cover


def first_in_cells(xyz: np.ndarray, origin: np.ndarray, size: float) -> np.ndarray:
    """The first point (lowest index) of every occupied cube of side ``size`` from ``origin``,
    ascending, (cells,) int64.

    One plain sort of ``cell * N + index`` gives both the cells and their first points; it is
    several times faster than ``np.unique(..., return_index=True)`` (a stable argsort).
    """
    n = xyz.shape[0]
    cells = [np.floor((xyz[:, a] - origin[a]) / size).astype(np.int64) for a in range(3)]
    dims = [int(c.max()) + 1 for c in cells]
    if math.prod(dims) >= (2**62) // max(n, 1):  # cell * N + index would overflow
        keys, _ = cell_keys(xyz, size, origin=origin)
        return np.sort(np.unique(keys, return_index=True)[1]).astype(np.int64)
    key = (cells[0] * dims[1] + cells[1]) * dims[2] + cells[2]
    del cells
    key *= n
    key += np.arange(n, dtype=np.int64)
    key.sort()
    cell = key // n
    starts = np.flatnonzero(cell[1:] != cell[:-1]) + 1
    first = key[np.concatenate(([0], starts))] % n
    first.sort()
    return first


def segment_colours(segments: np.ndarray, *, seed: int = 0) -> np.ndarray:
    """A random, fixed colour per segment id (same id, same colour), (N, 3) uint8."""
    ids, inverse = np.unique(segments, return_inverse=True)
    table = np.random.default_rng(seed).integers(40, 235, size=(ids.size, 3), dtype=np.uint8)
    return table[inverse.reshape(-1)]


def group_points(labels: np.ndarray, changed: np.ndarray) -> dict[tuple[int, bool], np.ndarray]:
    """Indices of the points of each (class, changed by fusion) pair that has any.

    The viewer draws each group as its own node, so hiding a class or showing only the changed
    points is a visibility switch, not a new upload. Labels outside 0..12 form class -1.
    """
    cls = np.where((labels >= 0) & (labels < NUM_CLASSES), labels, UNLABELLED).astype(np.int8)
    # 0..27 fits int8, for which numpy's stable sort is a radix sort (15x faster than int64's)
    key = (cls + 1) * 2 + changed.astype(np.int8)
    order = np.argsort(key, kind="stable")
    bounds = np.flatnonzero(np.diff(key[order])) + 1
    groups: dict[tuple[int, bool], np.ndarray] = {}
    for part in np.split(order, bounds):
        if part.size:
            k = int(key[part[0]])
            groups[(k // 2 - 1, bool(k % 2))] = part
    return groups


def load_scene(
    result_path: str | os.PathLike[str],
    report_path: str | os.PathLike[str] | None = None,
    *,
    max_points: int = MAX_PANEL_POINTS,
) -> SceneData:
    """Read a result file (and its report) into the viewer's panel data.

    Above ``max_points``, the points shown are an even sample of the file's rows
    (:func:`web.result_reader.sample_rows`, ``CANDIDATES_PER_POINT`` per point shown) thinned
    to one point per voxel; a binary PLY is read block by block, so neither the time nor the
    memory this takes holds the whole file (:mod:`web.result_reader`).

    Parameters
    ----------
    result_path : path
        A scan written by ``jointseg segment`` or the job service (any format ``read_scan``
        reads; the service writes PLY).
    report_path : path, optional
        The job's report.json; a missing or unreadable report only loses the score table.
    max_points : int
        Most points per panel; larger scans are down-sampled.

    Returns
    -------
    SceneData

    Raises
    ------
    ScanFormatError
        When the file cannot be read or lacks the pipeline's fields.
    """
    if max_points < 1:
        raise ValueError(f"max_points must be at least 1, got {max_points}")
    sample = read_sample(result_path, CANDIDATES_PER_POINT * max_points)
    report = read_report(report_path)
    to_work = work_transform(report)
    levelled = sample.xyz if to_work is None else sample.xyz @ to_work[:3, :3].T + to_work[:3, 3]
    kept, voxel = voxel_downsample(levelled, max_points)
    index = None if voxel is None and sample.rows.size == sample.total else kept  # None: all

    def pick(a: np.ndarray) -> np.ndarray:
        return a if index is None else a[index]

    xyz = pick(levelled)
    lo, hi = robust_box(xyz)
    centre = (lo + hi) / 2.0
    rgb = pick(sample.rgb) if sample.rgb is not None else np.full((xyz.shape[0], 3), 160, np.uint8)
    shown = (xyz - centre).astype(np.float32)
    network, fused = pick(sample.network), pick(sample.fused)
    data = SceneData(
        xyz=shown,
        centre=centre,
        extent=hi - lo,
        rgb=np.ascontiguousarray(rgb),
        network=network,
        fused=fused,
        truth=None if sample.truth is None else pick(sample.truth),
        segments=pick(sample.segments),
        changed=network != fused,
        total_points=sample.total,
        voxel=voxel,
        spacing=estimate_spacing(shown),
        counts=sample.counts,
        report=report,
        confidence=None if sample.confidence is None else pick(sample.confidence),
        to_work=to_work,
        instance=None if sample.instance is None else pick(sample.instance),
        rows=pick(sample.rows).astype(np.int64),
    )
    log.info(
        "loaded %s: %d of %d points shown (voxel %s)",
        result_path,
        shown.shape[0],
        sample.total,
        "none" if voxel is None else f"{voxel:.4f} m",
    )
    return data


def axis_bounds(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis minimum and maximum of (N, 3) points, float64 (column by column: ``min(axis=0)``
    on an (N, 3) array is more than ten times slower)."""
    if xyz.shape[0] == 0:
        return np.zeros(3), np.zeros(3)
    lo = np.array([xyz[:, a].min() for a in range(xyz.shape[1])], dtype=np.float64)
    hi = np.array([xyz[:, a].max() for a in range(xyz.shape[1])], dtype=np.float64)
    return lo, hi


def robust_box(xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The room's box, float64: per axis the :data:`ROBUST_QUANTILES` of (N, 3) points (of an
    even sample of :data:`ROBUST_SAMPLE` of them) widened by :data:`ROBUST_MARGIN`, within the
    points' bounding box. A scan without stray points gets its bounding box; a stray point
    falls outside."""
    if xyz.shape[0] == 0:
        return np.zeros(3), np.zeros(3)
    step = max(1, xyz.shape[0] // ROBUST_SAMPLE)
    sample = np.asarray(xyz[::step], dtype=np.float64)
    lo, hi = np.quantile(sample, ROBUST_QUANTILES, axis=0)
    margin = ROBUST_MARGIN * (hi - lo)
    low, high = axis_bounds(xyz)
    return np.maximum(lo - margin, low), np.minimum(hi + margin, high)


def levelled_xyz(xyz: np.ndarray, report: dict[str, Any] | None) -> np.ndarray:
    """The points as the pipeline saw them (z up, metres: the report's ``frame.to_work``), so
    a y-up or millimetre scan is shown standing, at the size the viewer's spacing expects."""
    matrix = work_transform(report)
    return xyz if matrix is None else xyz @ matrix[:3, :3].T + matrix[:3, 3]


def work_transform(report: dict[str, Any] | None) -> np.ndarray | None:
    """The report's ``frame.to_work`` as a 4x4 matrix, None when the scan was used as stored
    (or the entry is missing or unusable)."""
    frame = (report or {}).get("frame")
    if not isinstance(frame, dict) or frame.get("identity", True) or "to_work" not in frame:
        return None
    try:
        matrix = np.asarray(frame["to_work"], dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
        return None
    if abs(np.linalg.det(matrix[:3, :3])) < 1e-12:
        return None
    return matrix


def read_report(path: str | os.PathLike[str] | None) -> dict[str, Any] | None:
    """The report.json as a dict, None when there is none or it is not a JSON object."""
    if path is None:
        return None
    try:
        body = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        log.warning("report %s not shown: %s", path, exc)
        return None
    return body if isinstance(body, dict) else None


class SceneCache:
    """The last few loaded results, so viewers switching back and forth do not re-read files.

    Bounded by entries, so memory does not grow with the number of jobs viewed; an entry is
    reloaded when its file changed (path, size and modification time are the key).
    """

    def __init__(self, size: int = 2, *, max_points: int = MAX_PANEL_POINTS) -> None:
        self.size = size
        self.max_points = max_points
        self._entries: LRUCache[tuple[Any, ...], SceneData] = LRUCache(size)

    def __len__(self) -> int:
        return len(self._entries)

    def load(self, result_path: Path, report_path: Path | None = None) -> SceneData:
        """``load_scene`` through the cache."""
        stat = result_path.stat()
        key = (str(result_path), stat.st_size, stat.st_mtime_ns, str(report_path))
        cached = self._entries.get(key)
        if cached is not None:
            return cached
        data = load_scene(result_path, report_path, max_points=self.max_points)
        self._entries.put(key, data)
        return data
