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
from jointseg.exceptions import ScanFormatError
from jointseg.grouping import cell_keys
from jointseg.io import read_scan
from jointseg.spacing import estimate_spacing
from server.lru import LRUCache

log = logging.getLogger(__name__)

#: Most points one panel shows; the full resolution stays in the downloads.
MAX_PANEL_POINTS = 2_000_000
#: Result fields the viewer needs (written by jointseg.pipeline.outputs.annotate).
REQUIRED_FIELDS = ("network_label", "segment", "fused_label")


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
#: Left-to-right order of the panels in the scene.
PANELS: tuple[Panel, ...] = (RAW, NETWORK, FUSED, TRUTH, SEGMENTS)


@dataclass(frozen=True, eq=False)
class SceneData:
    """A result file reduced to what the viewer draws.

    Attributes
    ----------
    xyz : ndarray of shape (M, 3), float32, metres
        Shown points, centred on the scan's bounding-box centre (float32 keeps millimetres
        within kilometres of the centre; viser's default float16 would not).
    centre : ndarray of shape (3,), float64
        What was subtracted.
    extent : ndarray of shape (3,), float64, metres
        Size of the shown points' bounding box.
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

    @property
    def panels(self) -> tuple[Panel, ...]:
        """The panels this result can show (ground truth only when it has one)."""
        return tuple(p for p in PANELS if p is not TRUTH or self.truth is not None)

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
        if panel is NETWORK:
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
        return colourise(self.labels_of(panel))


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
    lo = xyz.min(axis=0)
    span = np.maximum(xyz.max(axis=0) - lo, 1e-6)
    # a scan is mostly surfaces: start from the bounding box's surface area per point
    area = 2.0 * (span[0] * span[1] + span[0] * span[2] + span[1] * span[2])
    voxel = math.sqrt(area / max_points)
    for _ in range(32):
        keys, _ = cell_keys(xyz, voxel, origin=lo)
        _, first = np.unique(keys, return_index=True)
        if first.size <= max_points:
            return np.sort(first).astype(np.int64), float(voxel)
        # occupied cells scale about as 1 / voxel^2 on surfaces
        voxel *= max(math.sqrt(first.size / max_points), 1.0) * 1.02
    raise RuntimeError("voxel down-sampling did not converge")  # pragma: no cover


def segment_colours(segments: np.ndarray, *, seed: int = 0) -> np.ndarray:
    """A random, fixed colour per segment id (same id, same colour), (N, 3) uint8."""
    ids, inverse = np.unique(segments, return_inverse=True)
    table = np.random.default_rng(seed).integers(40, 235, size=(ids.size, 3), dtype=np.uint8)
    return table[inverse.reshape(-1)]


def class_counts(labels: np.ndarray) -> np.ndarray:
    """Points per class, (NUM_CLASSES + 1,) int64; the last entry counts unlabelled points."""
    ok = (labels >= 0) & (labels < NUM_CLASSES)
    counts = np.bincount(labels[ok], minlength=NUM_CLASSES).astype(np.int64)
    return np.append(counts, np.int64(labels.size - int(ok.sum())))


def group_points(labels: np.ndarray, changed: np.ndarray) -> dict[tuple[int, bool], np.ndarray]:
    """Indices of the points of each (class, changed by fusion) pair that has any.

    The viewer draws each group as its own node, so hiding a class or showing only the changed
    points is a visibility switch, not a new upload. Labels outside 0..12 form class -1.
    """
    cls = np.where((labels >= 0) & (labels < NUM_CLASSES), labels, UNLABELLED).astype(np.int64)
    key = (cls + 1) * 2 + changed.astype(np.int64)
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

    Parameters
    ----------
    result_path : path
        A scan written by ``jointseg segment`` or the job service (any format ``read_scan``
        reads; the service writes PLY).
    report_path : path, optional
        The job's report.json; a missing or unreadable report only loses the score table.
    max_points : int
        Most points per panel; larger scans are voxel-down-sampled.

    Returns
    -------
    SceneData

    Raises
    ------
    ScanFormatError
        When the file cannot be read or lacks the pipeline's fields.
    """
    scan = read_scan(result_path)
    missing = [f for f in REQUIRED_FIELDS if f not in scan.fields]
    if missing:
        raise ScanFormatError(
            f"{result_path}: not a jointseg result, missing field(s) {', '.join(missing)}"
        )
    network = np.asarray(scan.fields["network_label"], dtype=np.int32)
    fused = np.asarray(scan.fields["fused_label"], dtype=np.int32)
    counts = {"network": class_counts(network), "fused": class_counts(fused)}
    if scan.labels is not None:
        counts["truth"] = class_counts(scan.labels)
    index, voxel = voxel_downsample(scan.xyz, max_points)
    full = index.size == len(scan)

    def pick(a: np.ndarray) -> np.ndarray:
        return a if full else a[index]

    xyz = pick(scan.xyz)
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    centre = (lo + hi) / 2.0
    rgb = scan.rgb if scan.rgb is not None else np.full((len(scan), 3), 160, np.uint8)
    shown = (xyz - centre).astype(np.float32)
    data = SceneData(
        xyz=shown,
        centre=centre,
        extent=hi - lo,
        rgb=np.ascontiguousarray(pick(rgb)),
        network=pick(network),
        fused=pick(fused),
        truth=None if scan.labels is None else pick(scan.labels),
        segments=pick(np.asarray(scan.fields["segment"], dtype=np.int32)),
        changed=pick(network != fused),
        total_points=len(scan),
        voxel=voxel,
        spacing=estimate_spacing(shown),
        counts=counts,
        report=read_report(report_path),
    )
    log.info(
        "loaded %s: %d of %d points shown (voxel %s)",
        result_path,
        shown.shape[0],
        len(scan),
        "none" if voxel is None else f"{voxel:.4f} m",
    )
    return data


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
