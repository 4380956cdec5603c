"""A big scan end to end in bounded memory: spill, tiles one by one, merge, streamed output.

This is the single-process path (``jointseg segment`` on a scan above
``TileParams.max_points``); the job service runs the same three steps (``tile_store.prepare``,
``tile_run.run_tile``, ``tile_merge.merge``) as separate queue tasks so that several workers
share one scan. Peak memory is one tile's run plus the per-point outputs (13 bytes a point),
never the whole scan's probabilities.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.io.stream import ScanChunks, open_chunks, open_writer
from jointseg.network.backends import Predictor
from jointseg.pipeline.config import PipelineConfig
from jointseg.pipeline.tile_merge import MergedScan, merge
from jointseg.pipeline.tile_run import run_tile
from jointseg.pipeline.tile_store import CHUNK_POINTS, TilePlan, prepare
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TiledRun:
    """A finished tiled run: the merged outputs, the plan and the JSON-ready report."""

    merged: MergedScan
    plan: TilePlan
    report: dict[str, Any]


class TileProgress:
    """Progress of one tile's stages as a fraction of all tiles (``(i + f) / n``), so a bar
    per stage runs once from 0 to 1 over the whole scan."""

    def __init__(self, progress: ProgressFn | None, index: int, count: int) -> None:
        self.progress = progress
        self.index = index
        self.count = count

    def __call__(self, stage: str, fraction: float) -> None:
        report(self.progress, stage, (self.index + fraction) / self.count)


def run_tiled(
    source: Path,
    output: Path,
    config: PipelineConfig,
    *,
    predictor: Predictor,
    max_points: int,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
    workdir: Path | None = None,
) -> TiledRun:
    """Segment ``source`` tile by tile and write ``output`` with the pipeline's fields.

    Parameters
    ----------
    source, output : Path
        Input scan; output scan (streamed for LAS/LAZ and PLY, written atomically).
    config : PipelineConfig
        ``config.tiles`` sets the tile size and overlap.
    predictor : Predictor
    max_points : int
        Refuse larger scans.
    progress : callable, optional
        Stages ``read``, ``plan``, ``network`` and ``geometry`` (over all tiles), ``tiles``,
        ``join``, ``fusion`` and ``write``.
    cancel : object with ``is_set()``, optional
    workdir : Path, optional
        Folder for the spilled scan and the tiles' results (about 60 bytes a point), removed
        at the end; default: a temporary folder beside ``output``.

    Returns
    -------
    TiledRun

    Raises
    ------
    ScanFormatError, ConfigError, Cancelled
    """
    started = time.perf_counter()
    own = workdir is None
    work = Path(tempfile.mkdtemp(prefix=".jointseg-tiles-", dir=output.parent)) if own else workdir
    assert work is not None
    timings: dict[str, float] = {}
    try:
        with open_chunks(source, max_points=max_points) as chunks:
            t = time.perf_counter()
            plan = prepare_from(
                chunks,
                work,
                config,
                source=source.name,
                predictor=predictor,
                progress=progress,
                cancel=cancel,
            )
            timings["prepare"] = time.perf_counter() - t
            t = time.perf_counter()
            _run_tiles(work, plan, config, predictor, progress, cancel)
            timings["tiles"] = time.perf_counter() - t
            merged = merge(work, config, plan=plan, progress=progress, cancel=cancel)
            timings.update(merged.timings)
            check_cancel(cancel)
            t = time.perf_counter()
            write_merged(chunks, merged, plan, output, progress=progress)
            timings["write"] = time.perf_counter() - t
    finally:
        if own:
            shutil.rmtree(work, ignore_errors=True)
    timings["total"] = time.perf_counter() - started
    return TiledRun(merged, plan, tiled_report(merged, plan, config, timings))


def _run_tiles(
    work: Path,
    plan: TilePlan,
    config: PipelineConfig,
    predictor: Predictor,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
) -> None:
    """Run the plan's tiles one after the other in this process (one tile's memory at a time)."""
    for box in plan.tiles:
        check_cancel(cancel)
        tile_progress = TileProgress(progress, box.index, len(plan.tiles))
        run_tile(
            work,
            box.index,
            config,
            predictor=predictor,
            plan=plan,
            progress=tile_progress,
            cancel=cancel,
        )
        report(progress, "tiles", (box.index + 1) / len(plan.tiles))


def prepare_from(
    chunks: ScanChunks,
    workdir: Path,
    config: PipelineConfig,
    *,
    source: str,
    predictor: Predictor,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> TilePlan:
    """:func:`~jointseg.pipeline.tile_store.prepare` of an opened scan with the run's tile,
    geometry and seed settings (the one-process run and the service's plan task)."""
    return prepare(
        chunks.chunks(CHUNK_POINTS),
        chunks.count,
        workdir,
        source=source,
        tiles=config.tiles,
        geometry=config.geometry,
        seed=config.seed,
        predictor=predictor,
        progress=progress,
        cancel=cancel,
    )


def annotated_chunks(chunks: Iterator[Scan], merged: MergedScan) -> Iterator[Scan]:
    """The input's chunks with the pipeline's fields, as :func:`annotate` gives them."""
    start = 0
    for chunk in chunks:
        stop = start + len(chunk)
        yield chunk.with_fields(
            network_label=merged.network_label[start:stop].astype(np.int32),
            network_confidence=merged.network_confidence[start:stop],
            segment=merged.segment[start:stop],
            fused_label=merged.fused_label[start:stop].astype(np.int32),
            fused_confidence=merged.fused_confidence[start:stop],
        )
        start = stop


def write_merged(
    chunks: ScanChunks,
    merged: MergedScan,
    plan: TilePlan,
    output: Path,
    *,
    progress: ProgressFn | None = None,
) -> None:
    """Stream the input again, chunk by chunk, into ``output`` with the pipeline's fields."""
    bounds = (np.array(plan.lower), np.array(plan.upper))
    stream = annotated_chunks(chunks.chunks(CHUNK_POINTS), merged)
    first = next(stream)
    written = 0
    with open_writer(output, count=plan.points, like=first, bounds=bounds) as writer:
        for chunk in _prepend(first, stream):
            writer.write(chunk)
            written += len(chunk)
            report(progress, "write", written / plan.points)


def _prepend(first: Scan, rest: Iterator[Scan]) -> Iterator[Scan]:
    yield first
    yield from rest


def tiled_report(
    merged: MergedScan, plan: TilePlan, config: PipelineConfig, timings: dict[str, float]
) -> dict[str, Any]:
    """The report of a tiled run, with the same keys as an untiled run's plus ``tiles``."""
    return {
        "points": plan.points,
        "segments": merged.n_segments,
        "labels_changed": merged.labels_changed,
        "segments_split": None,
        "segments_kept": None,
        "timings_s": timings,
        "steps_s": {"tiles": merged.tile_timings},
        "params": {
            "geometry": plan.geometry.model_dump(),
            "fusion": config.fusion.model_dump(),
            "network": config.network.model_dump(mode="json"),
            "seed": config.seed,
        },
        "tiles": {
            "count": len(plan.tiles),
            "max_points": plan.params.max_points,
            "overlap_m": plan.params.overlap,
            "core_points": [box.core_points for box in plan.tiles],
            "outer_points": [box.outer_points for box in plan.tiles],
            "tile_segments": merged.tile_segments,
            "joins": merged.joins,
        },
        "metrics": None
        if merged.metrics is None
        else {name: m.model_dump() for name, m in merged.metrics.items()},
    }
