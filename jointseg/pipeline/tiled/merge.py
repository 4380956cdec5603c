"""Joining the tiles of a big scan: one segment numbering, the vote, per-point outputs.

Every point takes its network output and its segment from the tile whose core holds it. A
segment that crosses a tile border was cut in two by the tiling; both tiles saw the overlap,
so the points there carry a segment from each side. Two segments are joined when each holds
the majority of the other's points in that overlap (mutual majority, at least
``MIN_LINK_POINTS``): a wall that spans tiles becomes one segment, while a segment that only
grazes another across the border is not glued to it. The joins are a union-find (connected
components of the link graph), so a wall across three tiles is one segment too.

The vote then runs on whole segments, in batches of about ``TileParams.max_points`` points,
with the scan-wide totals it needs (:class:`jointseg.fusion.ScanTotals`) and cells on the
absolute grid, so a segment is voted on exactly as if the whole scan were in memory. Only the
outputs (labels, confidences, segment) exist for the whole scan at once.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from jointseg.fusion import ScanTotals, StructureHint, fuse
from jointseg.fusion.offers import disagreement_share, normalised_entropy
from jointseg.fusion.thresholds import ClassTally
from jointseg.grouping import compact_ids
from jointseg.metrics import SegmentationMetrics, evaluate, segment_majority
from jointseg.network.presence import drop_absent
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.pipeline.config import PipelineConfig
from jointseg.pipeline.tiled.run import TileNetwork, load_cells, load_result
from jointseg.pipeline.tiled.store import CHUNK_POINTS, TilePlan, column_chunks, read_plan
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report

log = logging.getLogger(__name__)

#: Least overlap points two segments must share to be joined across a tile border.
MIN_LINK_POINTS = 20


@dataclass(frozen=True)
class MergedScan:
    """The outputs of a tiled run for every point, in the scan's order.

    Attributes
    ----------
    network_label : ndarray of shape (N,), uint8
    network_confidence : ndarray of shape (N,), float32
    segment : ndarray of shape (N,), int32
        Segments 0..S-1, joined across tile borders.
    fused_label : ndarray of shape (N,), uint8
    fused_confidence : ndarray of shape (N,), float32
    joins : int
        Segment pairs joined across tile borders.
    """

    network_label: np.ndarray
    network_confidence: np.ndarray
    segment: np.ndarray
    fused_label: np.ndarray
    fused_confidence: np.ndarray
    joins: int
    tile_segments: int
    timings: dict[str, float] = field(default_factory=dict)
    tile_timings: list[dict[str, float]] = field(default_factory=list)
    metrics: dict[str, SegmentationMetrics] | None = None

    @property
    def n_segments(self) -> int:
        """Segments after joining."""
        return int(self.segment.max()) + 1 if len(self.segment) else 0

    @property
    def labels_changed(self) -> int:
        """Points whose label the vote changed."""
        return int(np.count_nonzero(self.fused_label != self.network_label))


@dataclass
class _Gathered:
    """Per-point arrays filled from the tiles' cores, and the overlap links."""

    segment: np.ndarray
    labels: np.ndarray
    confidence: np.ndarray
    main_plane: np.ndarray
    structure: np.ndarray
    structure_confidence: np.ndarray
    link_from: list[np.ndarray]
    link_point: list[np.ndarray]
    segment_tile: np.ndarray
    entropy_sum: float
    tile_timings: list[dict[str, float]]
    point_cell: np.ndarray | None = None
    cells: CellTable | None = None
    #: each point's row in ``cells`` (found once from ``point_cell``, which is then dropped)
    point_row: np.ndarray | None = None
    #: the network's output per class over the whole scan (the vote's thresholds)
    tally: ClassTally = field(default_factory=ClassTally.empty)


@dataclass(frozen=True)
class CellTable:
    """The whole scan's network outputs per sub-sampled cell, added over the tiles' crops."""

    ids: np.ndarray
    probs: np.ndarray

    def rows(self, cells: np.ndarray) -> np.ndarray:
        """The rows of the cells ``cells`` in the table (a binary search each: on a 20 M-point
        floor 4-5 s, so a merge searches once and keeps the rows)."""
        return np.searchsorted(self.ids, cells)


def merge(
    workdir: Path,
    config: PipelineConfig,
    *,
    plan: TilePlan | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> MergedScan:
    """Join the tiles' segments across borders, vote, and score against ground truth.

    Parameters
    ----------
    workdir : Path
        A prepared folder whose tiles have all been run.
    config : PipelineConfig
        Its ``fusion`` section is the vote.
    plan : TilePlan, optional
    progress : callable, optional
        ``progress("join" | "fusion", fraction)``.
    cancel : object with ``is_set()``, optional

    Returns
    -------
    MergedScan

    Raises
    ------
    ConfigError
        When a tile has no result.
    """
    plan = plan or read_plan(workdir)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    gathered = _gather(workdir, plan, progress, cancel)
    if gathered.point_cell is not None:
        _network_outputs(workdir, plan, gathered, config)  # point_cell -> point_row
    joined, joins = join_segments(gathered)
    _, segment = compact_ids(joined[gathered.segment])
    segment = segment.astype(np.int32)
    timings["join"] = time.perf_counter() - t
    report(progress, "join", 1.0)
    t = time.perf_counter()
    fused, confidence = _vote(workdir, plan, config, gathered, segment, progress, cancel)
    timings["fusion"] = time.perf_counter() - t
    t = time.perf_counter()
    metrics = _metrics(workdir, plan, gathered.labels, fused, segment)
    timings["metrics"] = time.perf_counter() - t
    merged = MergedScan(
        network_label=gathered.labels,
        network_confidence=gathered.confidence,
        segment=segment,
        fused_label=fused,
        fused_confidence=confidence,
        joins=joins,
        tile_segments=len(gathered.segment_tile),
        timings=timings,
        tile_timings=gathered.tile_timings,
        metrics=metrics,
    )
    log.info(
        "merge: %d tiles, %d segments joined into %d (%d joins), %d labels changed",
        len(plan.tiles),
        merged.tile_segments,
        merged.n_segments,
        joins,
        merged.labels_changed,
    )
    return merged


def _gather(
    workdir: Path, plan: TilePlan, progress: ProgressFn | None, cancel: CancelToken | None
) -> _Gathered:
    """Fill the per-point arrays from each tile's core; keep each tile's margin links."""
    n = plan.points
    out = _Gathered(
        segment=np.full(n, -1, dtype=np.int32),
        labels=np.zeros(n, dtype=np.uint8),
        confidence=np.zeros(n, dtype=np.float32),
        main_plane=np.zeros(n, dtype=bool),
        structure=np.full(n, -1, dtype=np.int8),
        structure_confidence=np.zeros(n, dtype=np.float32),
        link_from=[],
        link_point=[],
        segment_tile=np.zeros(0, dtype=np.int32),
        entropy_sum=0.0,
        tile_timings=[],
    )
    offset = 0
    owners: list[np.ndarray] = []
    for box in plan.tiles:
        check_cancel(cancel)
        tile = load_result(workdir, box.index)
        core_idx = tile.core_index
        out.segment[core_idx] = tile.segments[tile.core] + offset
        out.main_plane[core_idx] = tile.main_plane[tile.core]
        out.structure[core_idx] = tile.structure[tile.core]
        out.structure_confidence[core_idx] = tile.structure_confidence[tile.core]
        _take_network(out, tile.network, core_idx)
        margin = ~tile.core & (tile.segments >= 0)
        out.link_from.append(tile.segments[margin].astype(np.int64) + offset)
        out.link_point.append(tile.index[margin])
        owners.append(np.full(tile.n_segments, box.index, dtype=np.int32))
        out.entropy_sum += tile.network.entropy_sum
        out.tile_timings.append(tile.timings)
        offset += tile.n_segments
        report(progress, "join", 0.8 * (box.index + 1) / len(plan.tiles))
    if (out.segment < 0).any():
        missing = int(np.count_nonzero(out.segment < 0))
        raise RuntimeError(f"{missing} points are in no tile's core (a planning bug)")
    out.segment_tile = np.concatenate(owners) if owners else out.segment_tile
    return out


def _take_network(out: _Gathered, network: TileNetwork, core_idx: np.ndarray) -> None:
    """Put a tile's network outputs at its core points: the cells they read from (summed over
    tiles later), or the labels and confidences themselves."""
    if network.per_cell:
        if out.point_cell is None:
            out.point_cell = np.full(len(out.segment), -1, dtype=np.int64)
        out.point_cell[core_idx] = network.point_cell
        return
    out.labels[core_idx] = network.labels
    out.confidence[core_idx] = network.confidence
    if network.probs is not None and network.labels is not None:
        out.tally += ClassTally.of(network.labels, network.probs)


def _network_outputs(
    workdir: Path, plan: TilePlan, gathered: _Gathered, config: PipelineConfig
) -> None:
    """Add the tiles' sums per cell, take out the classes the whole scan does not hold (as the
    untiled inference does), give every point its cell's label and confidence."""
    ids_parts, sum_parts, seen_parts = [], [], []
    for box in plan.tiles:
        ids, sums, seen = load_cells(workdir, box.index)
        ids_parts.append(ids)
        sum_parts.append(sums)
        seen_parts.append(seen)
    ids, inverse = np.unique(np.concatenate(ids_parts), return_inverse=True)
    del ids_parts
    seen = np.bincount(inverse, weights=np.concatenate(seen_parts), minlength=len(ids))
    sums = np.concatenate(sum_parts)
    del sum_parts
    probs = np.empty((len(ids), sums.shape[1]), dtype=np.float32)
    for c in range(sums.shape[1]):
        probs[:, c] = np.bincount(inverse, weights=sums[:, c], minlength=len(ids)) / np.maximum(
            seen, 1
        )
    del sums, inverse
    options = config.network.options()
    if isinstance(options, RandLANetParams):
        probs = drop_absent(probs, options.absent_share, options.absent_max_cells)
    gathered.cells = CellTable(ids, probs)
    assert gathered.point_cell is not None
    point_row = np.empty(plan.points, dtype=np.int32 if len(ids) < 2**31 else np.int64)
    for start in range(0, plan.points, CHUNK_POINTS):
        found = gathered.cells.rows(gathered.point_cell[start : start + CHUNK_POINTS])
        point_row[start : start + len(found)] = found
        rows = probs[found]
        labels = rows.argmax(axis=1)
        gathered.labels[start : start + len(rows)] = labels
        gathered.tally += ClassTally.of(labels, rows)
        gathered.confidence[start : start + len(rows)] = rows.max(axis=1)
        gathered.entropy_sum += float(normalised_entropy(rows).sum())
    gathered.point_row, gathered.point_cell = point_row, None


def join_segments(gathered: _Gathered) -> tuple[np.ndarray, int]:
    """Component of every tile segment after joining across borders, and the number of joins.

    A margin point links its segment in the tile that saw it as margin (``a``) with its
    segment in the tile that owns it (``b``); a pair is joined when it holds more than half
    of ``a``'s margin points and more than half of ``b``'s points in that tile's margin.
    """
    n_total = len(gathered.segment_tile)
    a = np.concatenate(gathered.link_from) if gathered.link_from else np.zeros(0, np.int64)
    points = np.concatenate(gathered.link_point) if gathered.link_point else np.zeros(0, np.int64)
    b = gathered.segment[points].astype(np.int64)
    if len(a) == 0:
        return np.arange(n_total), 0
    pairs, counts = np.unique(a * n_total + b, return_counts=True)
    pa, pb = pairs // n_total, pairs % n_total
    from_total = np.bincount(pa, weights=counts, minlength=n_total)
    # b's points seen as margin by a's tile: group by (b, a's tile)
    n_tiles = int(gathered.segment_tile.max()) + 1
    key = pb * n_tiles + gathered.segment_tile[pa]
    _, where = np.unique(key, return_inverse=True)
    to_total = np.bincount(where, weights=counts)[where]
    keep = (counts >= MIN_LINK_POINTS) & (2 * counts > from_total[pa]) & (2 * counts > to_total)
    graph = coo_matrix(
        (np.ones(int(keep.sum()), dtype=np.int8), (pa[keep], pb[keep])), shape=(n_total, n_total)
    )
    _, component = connected_components(graph, directed=False)
    return component, int(keep.sum())


def _batches(segment: np.ndarray, batch_points: int) -> tuple[np.ndarray, int]:
    """Batch of every segment: consecutive segments up to about ``batch_points`` points (a
    bigger segment alone), so each batch holds whole segments."""
    sizes = np.bincount(segment)
    starts = np.cumsum(sizes) - sizes
    batch = starts // max(batch_points, 1)
    _, batch = np.unique(batch, return_inverse=True)
    return batch, int(batch.max()) + 1


def _vote(
    workdir: Path,
    plan: TilePlan,
    config: PipelineConfig,
    gathered: _Gathered,
    segment: np.ndarray,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
) -> tuple[np.ndarray, np.ndarray]:
    """Fused labels and confidences, voted batch by batch of whole segments."""
    n = plan.points
    fused = np.empty(n, dtype=np.uint8)
    confidence = np.empty(n, dtype=np.float32)
    totals = ScanTotals(
        points=n,
        mean_entropy=gathered.entropy_sum / max(n, 1),
        disagreement=disagreement_share(segment, int(segment.max()) + 1, gathered.labels),
        classes=gathered.tally,
    )
    seg_batch, n_batches = _batches(segment, plan.params.max_points)
    point_batch = seg_batch.astype(np.int32)[segment]
    del seg_batch
    for b in range(n_batches):
        check_cancel(cancel)
        members = np.flatnonzero(point_batch == b)
        xyz = _gather_xyz(workdir, plan, members)
        if gathered.cells is not None and gathered.point_row is not None:
            probs = gathered.cells.probs[gathered.point_row[members]]
        else:
            probs = _gather_probs(workdir, plan, members)
        result = fuse(
            xyz,
            segment[members],
            gathered.labels[members],
            probs,
            config.fusion,
            main_plane=gathered.main_plane[members],
            totals=totals,
            structure=StructureHint(
                gathered.structure[members], gathered.structure_confidence[members]
            ),
            has_colour=plan.has_rgb,
        )
        fused[members] = result.labels
        confidence[members] = result.confidence
        report(progress, "fusion", (b + 1) / n_batches)
    return fused, confidence


def _gather_xyz(workdir: Path, plan: TilePlan, members: np.ndarray) -> np.ndarray:
    """Coordinates of the points ``members`` (ascending) from the spilled columns."""
    xyz = np.empty((len(members), 3))
    for start, chunk, _, _ in column_chunks(workdir, plan.points, has_rgb=False, has_labels=False):
        a, b = np.searchsorted(members, [start, start + len(chunk)])
        if a < b:
            xyz[a:b] = chunk[members[a:b] - start]
    return xyz


def _gather_probs(workdir: Path, plan: TilePlan, members: np.ndarray) -> np.ndarray:
    """The owning tiles' probabilities at the points ``members`` (ascending), float32."""
    probs = np.empty((len(members), 13), dtype=np.float32)
    for box in plan.tiles:
        tile = load_result(workdir, box.index)
        tile_probs = tile.network.probs
        assert tile_probs is not None
        core_idx = tile.core_index  # ascending, like the probabilities' rows
        where = np.searchsorted(members, core_idx)
        hit = (where < len(members)) & (members[np.minimum(where, len(members) - 1)] == core_idx)
        if hit.any():
            probs[where[hit]] = tile_probs[np.flatnonzero(hit)]
    return probs


def _metrics(
    workdir: Path, plan: TilePlan, network: np.ndarray, fused: np.ndarray, segment: np.ndarray
) -> dict[str, SegmentationMetrics] | None:
    """Network, fused and oracle scores against the scan's ground truth, when it has any."""
    if not plan.has_labels:
        return None
    gt = np.empty(plan.points, dtype=np.int32)
    chunks = column_chunks(workdir, plan.points, has_rgb=False, has_labels=True)
    for start, _, _, labels in chunks:
        assert labels is not None
        gt[start : start + len(labels)] = labels
    if not (gt >= 0).any():
        return None
    return {
        "network": evaluate(gt, network),
        "fused": evaluate(gt, fused),
        "oracle": evaluate(gt, segment_majority(gt, segment)),
    }
