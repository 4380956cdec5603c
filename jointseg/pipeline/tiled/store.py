"""The work folder of a tiled run: the scan spilled to disk once, the tile plan, each tile's points.

A big scan is read once, chunk by chunk, into raw little-endian column files; the tile plan is
made from a strided sample of it; a second pass over those files (fast: they are plain arrays,
no decompression) lists each tile's points. Any process that sees the folder (a worker on
another machine, through the service's shared data directory) can then load one tile without
reading the scan again. Layout::

    plan.json              TilePlan
    points/xyz.f64         (N, 3) coordinates
    points/rgb.u8          (N, 3) colour, when the scan has colour
    points/labels.i16      (N,) ground truth, when the scan has it
    tiles/0003/index.i64   the tile's points (its outer box), ascending indices into the scan
    tiles/0003/result.npz  what the tile's run left (``tiled.run``)

Memory while preparing: one chunk, the sample and one tile's index list at a time.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from jointseg.boxes import in_box
from jointseg.exceptions import ConfigError, ScanFormatError
from jointseg.geometry.params import GeometryParams, ResolvedGeometryParams
from jointseg.pipeline.tile_params import TileParams
from jointseg.pipeline.tiled.grid import Tile, plan_tiles
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

log = logging.getLogger(__name__)

#: Points read per chunk from the input and from the spilled columns.
CHUNK_POINTS = 1_000_000
#: Points in the strided sample the plan's cuts are placed on.
SAMPLE_POINTS = 200_000
#: Points of the contiguous patch the geometry's thresholds are derived from.
PARAMS_POINTS = 1_000_000
PLAN_FILE = "plan.json"
PLAN_VERSION = 1


class TileBox(BaseModel):
    """One tile of the plan as stored: its boxes and how many points they hold."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    index: int
    core_min: tuple[float, float]
    core_max: tuple[float, float]
    outer_min: tuple[float, float]
    outer_max: tuple[float, float]
    core_points: int = 0
    outer_points: int = 0

    def tile(self) -> Tile:
        """The box as a :class:`Tile` (for its masks)."""
        return Tile(self.index, self.core_min, self.core_max, self.outer_min, self.outer_max)


class Anchoring(BaseModel):
    """The whole-scan crop plan shared by the tiles (``crops.npz``), when the network can."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    grid_size: float
    crops: int
    crop_size: int
    outside: int = 0


class TilePlan(BaseModel):
    """Everything a tile's run needs besides its points, written once to ``plan.json``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    version: int = PLAN_VERSION
    source: str
    points: int
    lower: tuple[float, float, float]
    upper: tuple[float, float, float]
    has_rgb: bool
    has_labels: bool
    tiles: list[TileBox]
    geometry: ResolvedGeometryParams
    params: TileParams
    anchoring: Anchoring | None = None
    frame: dict[str, Any] | None = None
    #: the networks that label the tiles (several for an ensemble), for the report
    networks: list[str] = Field(default_factory=list)


class _Columns:
    """The spilled scan's raw column files, in ``points/``."""

    def __init__(self, workdir: Path) -> None:
        self.folder = workdir / "points"
        self.xyz = self.folder / "xyz.f64"
        self.rgb = self.folder / "rgb.u8"
        self.labels = self.folder / "labels.i16"


def tile_folder(workdir: Path, index: int) -> Path:
    """The folder of tile ``index`` inside ``workdir``."""
    return workdir / "tiles" / f"{index:04d}"


def read_plan(workdir: Path) -> TilePlan:
    """The plan of a prepared work folder.

    Raises
    ------
    ConfigError
        When the folder holds no readable plan of this version.
    """
    path = workdir / PLAN_FILE
    try:
        plan = TilePlan.model_validate_json(path.read_bytes())
    except FileNotFoundError as exc:
        raise ConfigError(f"{workdir}: not a prepared tile folder (no {PLAN_FILE})") from exc
    except ValueError as exc:
        raise ConfigError(f"{path}: unreadable tile plan: {exc}") from exc
    if plan.version != PLAN_VERSION:
        raise ConfigError(f"{path}: tile plan version {plan.version}, expected {PLAN_VERSION}")
    return plan


def prepare(
    chunks: Iterator[Scan],
    count: int,
    workdir: Path,
    *,
    source: str,
    tiles: TileParams,
    geometry: GeometryParams,
    seed: int = 0,
    predictor: object | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
    frame: Callable[[], dict[str, Any]] | None = None,
) -> TilePlan:
    """Spill a scan into ``workdir``, plan its tiles and list each tile's points.

    Parameters
    ----------
    chunks : iterator of Scan
        The scan's points in order, in chunks (:func:`jointseg.io.stream.open_chunks`).
    count : int
        Points in the scan (the chunks must add up to it).
    workdir : Path
        An empty or missing folder.
    source : str
        The scan's name, for the plan and messages.
    tiles : TileParams
        Where the cuts go.
    geometry : GeometryParams
        The thresholds to resolve once for every tile (from a contiguous patch of the scan).
    seed : int
    predictor : Predictor, optional
        When it is a :class:`~jointseg.network.backends.TilePredictor`, the whole scan's crop
        plan is made here, so the tiles together give the labels of an untiled run.
    progress, cancel, frame
        ``progress("read", fraction)`` while spilling, ``("plan", fraction)`` while listing;
        ``frame()``, after the spill, gives the plan's frame entry (the chunks came levelled).

    Returns
    -------
    TilePlan
        Also written to ``workdir/plan.json``, last, so a folder with a plan is complete.

    Raises
    ------
    ScanFormatError
        When the chunks do not add up to ``count`` or the scan is empty.
    """
    if count <= 0:
        raise ScanFormatError(f"{source}: the scan has no points")
    columns = _Columns(workdir)
    columns.folder.mkdir(parents=True, exist_ok=True)
    sample, lower, upper, has_rgb, has_labels = _spill(
        chunks, count, columns, source=source, progress=progress, cancel=cancel
    )
    corners = np.array([lower[:2], upper[:2]])  # the plan's extent is the scan's, not the sample's
    planned = plan_tiles(np.concatenate([sample, corners]), count, tiles)
    patch = _patch_box(planned, sample, count)
    boxes, patch_scan = _list_tiles(
        columns, count, planned, patch, has_rgb, workdir, progress=progress, cancel=cancel
    )
    # deferred: the geometry's implementation loads open3d
    from jointseg.geometry.segmentation import scan_params

    resolved = scan_params(patch_scan, geometry, n_points=count, seed=seed)
    anchoring = _anchor(workdir, count, lower, planned, has_rgb, predictor, seed)
    plan = TilePlan(
        source=source, points=count, lower=_triple(lower), upper=_triple(upper),
        has_rgb=has_rgb, has_labels=has_labels, tiles=boxes, geometry=resolved, params=tiles,
        anchoring=anchoring, frame=None if frame is None else frame(),
        networks=[m.name for m in getattr(predictor, "members", [predictor]) if m is not None],
    )  # fmt: skip
    _write_plan(workdir, plan)
    log.info("tiles: %d points in %d tiles (%s)", count, len(boxes), source)
    return plan


def _write_plan(workdir: Path, plan: TilePlan) -> None:
    """Write ``plan.json`` through a temporary file and a rename, so a plan is never partial."""
    tmp = workdir / f".{PLAN_FILE}.tmp"
    tmp.write_text(plan.model_dump_json(indent=1))
    os.replace(tmp, workdir / PLAN_FILE)


def _anchor(
    workdir: Path,
    count: int,
    lower: np.ndarray,
    tiles: list[Tile],
    has_rgb: bool,
    predictor: object | None,
    seed: int,
) -> Anchoring | None:
    """The whole scan's sub-sample and crop plan (``crops.npz``), for a network that can
    share them among tiles; None for one that cannot (its tiles then run on their own)."""
    # deferred: the network's modules load torch
    from jointseg.network.anchored import anchored_cloud, crops_inside
    from jointseg.network.backends import TilePredictor

    if not isinstance(predictor, TilePredictor):
        return None
    upper_xy = np.array([max(t.outer_max[0] for t in tiles), max(t.outer_max[1] for t in tiles)])
    blocks = (
        (xyz, rgb)
        for _, xyz, rgb, _ in column_chunks(workdir, count, has_rgb=has_rgb, has_labels=False)
    )
    cloud = anchored_cloud(blocks, predictor.grid_size, lower)
    crops = predictor.plan(cloud, seed)
    outside = 0
    for tile in tiles:
        mine = crops_inside(crops, lower, np.array(tile.core_min), np.array(tile.core_max))
        centre = crops.centres[mine, :2].astype(np.float64) + lower[:2]
        reach_lo = centre - crops.radius[mine, None]
        reach_hi = centre + crops.radius[mine, None]
        # beyond an outer edge that is the scan's own edge there are no points to miss
        inner_lo = np.array(tile.outer_min) > lower[:2]
        inner_hi = np.array(tile.outer_max) < upper_xy
        short = ((reach_lo < tile.outer_min) & inner_lo) | ((reach_hi > tile.outer_max) & inner_hi)
        outside += int(np.count_nonzero(short.any(axis=1)))
    if outside:
        log.warning(
            "tiles: %d of %d crops reach beyond their tile's overlap margin; points near "
            "those tiles' borders may differ from an untiled run (raise tiles.overlap)",
            outside,
            len(crops),
        )
    np.savez(workdir / "crops.npz", centres=crops.centres, radius=crops.radius)
    return Anchoring(
        grid_size=predictor.grid_size,
        crops=len(crops),
        crop_size=crops.crop_size,
        outside=outside,
    )


def _triple(values: np.ndarray) -> tuple[float, float, float]:
    return (float(values[0]), float(values[1]), float(values[2]))


def _spill(
    chunks: Iterator[Scan],
    count: int,
    columns: _Columns,
    *,
    source: str,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool, bool]:
    """Write the chunks to the column files; return a strided x-y sample, the bounds, and
    whether the scan has colour and labels."""
    stride = max(1, math.ceil(count / SAMPLE_POINTS))
    samples: list[np.ndarray] = []
    lower = np.full(3, np.inf)
    upper = np.full(3, -np.inf)
    seen = 0
    has_rgb = has_labels = False
    files: dict[str, BinaryIO] = {}
    try:
        for chunk in chunks:
            check_cancel(cancel)
            if seen == 0:
                has_rgb, has_labels = chunk.rgb is not None, chunk.labels is not None
                files["xyz"] = open(columns.xyz, "wb")  # noqa: SIM115 - closed in finally
                if has_rgb:
                    files["rgb"] = open(columns.rgb, "wb")  # noqa: SIM115
                if has_labels:
                    files["labels"] = open(columns.labels, "wb")  # noqa: SIM115
            n = len(chunk)
            if n == 0:
                continue
            if seen + n > count:
                raise ScanFormatError(f"{source}: more points than the {count:,} announced")
            chunk.xyz.astype("<f8", copy=False).tofile(files["xyz"])
            if has_rgb:
                _require(chunk.rgb, "colour", source).astype("u1", copy=False).tofile(files["rgb"])
            if has_labels:
                labels = _require(chunk.labels, "labels", source)
                labels.astype("<i2").tofile(files["labels"])
            first = (-seen) % stride
            samples.append(chunk.xyz[first::stride, :2].copy())
            lower = np.minimum(lower, chunk.xyz.min(axis=0))
            upper = np.maximum(upper, chunk.xyz.max(axis=0))
            seen += n
            report(progress, "read", seen / count)
    finally:
        for fh in files.values():
            fh.close()
    if seen != count:
        raise ScanFormatError(f"{source}: {seen:,} points read, the file announced {count:,}")
    return np.concatenate(samples), lower, upper, has_rgb, has_labels


def _require(values: np.ndarray | None, what: str, source: str) -> np.ndarray:
    if values is None:
        raise ScanFormatError(f"{source}: {what} present in some chunks and not in others")
    return values


def _patch_box(tiles: list[Tile], sample: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """A box around the centre of the fullest tile's core holding about ``PARAMS_POINTS``
    points: the contiguous patch the geometry's thresholds come from."""
    owner_counts = [int(t.core_mask(sample).sum()) for t in tiles]
    best = tiles[int(np.argmax(owner_counts))]
    lo, hi = np.array(best.core_min), np.array(best.core_max)
    core_points = max(owner_counts) * count / max(len(sample), 1)
    share = min(1.0, PARAMS_POINTS / max(core_points, 1.0))
    half = (hi - lo) * math.sqrt(share) / 2
    centre = (lo + hi) / 2
    return centre - half, centre + half


def column_chunks(
    workdir: Path, count: int, *, has_rgb: bool, has_labels: bool
) -> Iterator[tuple[int, np.ndarray, np.ndarray | None, np.ndarray | None]]:
    """``(start, xyz, rgb, labels)`` for consecutive chunks of the spilled columns."""
    columns = _Columns(workdir)
    with open(columns.xyz, "rb") as fx:
        frgb = open(columns.rgb, "rb") if has_rgb else None  # noqa: SIM115
        flab = open(columns.labels, "rb") if has_labels else None  # noqa: SIM115
        try:
            for start in range(0, count, CHUNK_POINTS):
                n = min(CHUNK_POINTS, count - start)
                xyz = np.fromfile(fx, dtype="<f8", count=3 * n).reshape(n, 3)
                rgb = None if frgb is None else np.fromfile(frgb, "u1", 3 * n).reshape(n, 3)
                labels = None if flab is None else np.fromfile(flab, "<i2", n)
                if len(xyz) != n:
                    raise ScanFormatError(f"{columns.xyz}: spilled scan is truncated")
                yield start, xyz, rgb, labels
        finally:
            for fh in (frgb, flab):
                if fh is not None:
                    fh.close()


def _list_tiles(
    columns: _Columns,
    count: int,
    tiles: list[Tile],
    patch: tuple[np.ndarray, np.ndarray],
    has_rgb: bool,
    workdir: Path,
    *,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
) -> tuple[list[TileBox], Scan]:
    """Write each tile's outer-box point indices; count core and outer points; gather the
    patch the geometry's thresholds come from."""
    folders = [tile_folder(workdir, t.index) for t in tiles]
    for folder in folders:
        folder.mkdir(parents=True, exist_ok=True)
    handles = [open(folder / "index.i64", "wb") for folder in folders]  # noqa: SIM115
    core_points = np.zeros(len(tiles), dtype=np.int64)
    outer_points = np.zeros(len(tiles), dtype=np.int64)
    patch_xyz: list[np.ndarray] = []
    patch_rgb: list[np.ndarray] = []
    try:
        chunks = column_chunks(workdir, count, has_rgb=has_rgb, has_labels=False)
        for start, xyz, rgb, _ in chunks:
            check_cancel(cancel)
            xy = xyz[:, :2]
            for t, fh in zip(tiles, handles, strict=True):
                inside = np.flatnonzero(t.outer_mask(xy))
                (inside + start).astype("<i8").tofile(fh)
                outer_points[t.index] += len(inside)
                core_points[t.index] += int(np.count_nonzero(t.core_mask(xy[inside])))
            near = in_box(xy, patch[0], patch[1])
            patch_xyz.append(xyz[near])
            if rgb is not None:
                patch_rgb.append(rgb[near])
            report(progress, "plan", min(1.0, (start + len(xyz)) / count))
    finally:
        for fh in handles:
            fh.close()
    lost = count - int(core_points.sum())
    if lost:
        raise ConfigError(f"tile plan leaves {lost:,} points outside every core (a bug)")
    boxes = [
        TileBox(
            index=t.index,
            core_min=t.core_min,
            core_max=t.core_max,
            outer_min=t.outer_min,
            outer_max=t.outer_max,
            core_points=int(core_points[t.index]),
            outer_points=int(outer_points[t.index]),
        )
        for t in tiles
    ]
    patch_scan = Scan(np.concatenate(patch_xyz), np.concatenate(patch_rgb) if patch_rgb else None)
    return boxes, patch_scan


def load_tile(workdir: Path, plan: TilePlan, index: int) -> tuple[Scan, np.ndarray]:
    """Tile ``index``'s points (its outer box) as a Scan, and their indices in the scan.

    Raises
    ------
    ConfigError
        For a tile the plan does not have, or a folder missing its files.
    """
    if not 0 <= index < len(plan.tiles):
        raise ConfigError(f"tile {index} is not in the plan (0..{len(plan.tiles) - 1})")
    path = tile_folder(workdir, index) / "index.i64"
    try:
        wanted = np.fromfile(path, dtype="<i8")
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: tile index missing (folder not prepared?)") from exc
    xyz = np.empty((len(wanted), 3))
    rgb = np.empty((len(wanted), 3), dtype=np.uint8) if plan.has_rgb else None
    labels = np.empty(len(wanted), dtype=np.int32) if plan.has_labels else None
    chunks = column_chunks(workdir, plan.points, has_rgb=plan.has_rgb, has_labels=plan.has_labels)
    for start, cx, crgb, clab in chunks:
        a, b = np.searchsorted(wanted, [start, start + len(cx)])
        if a == b:
            continue
        local = wanted[a:b] - start
        xyz[a:b] = cx[local]
        if rgb is not None and crgb is not None:
            rgb[a:b] = crgb[local]
        if labels is not None and clab is not None:
            labels[a:b] = clab[local]
    return Scan(xyz, rgb, labels), wanted
