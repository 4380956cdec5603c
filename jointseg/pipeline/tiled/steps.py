"""The first and last of a tiled run's three steps, as the one-process run and the job service
call them (the middle one, ``run_tile``, is :mod:`jointseg.pipeline.tiled.run`'s).

``plan`` spills the scan and cuts it into tiles, ``run_tile`` runs network and geometry on one
tile, ``finish`` joins the tiles, votes and streams the output. ``jointseg segment`` calls them
one after the other (:func:`jointseg.pipeline.segment.segment_file`); the job service calls them
as separate queue tasks so that several workers share one scan. Peak memory is one tile's run
plus the per-point outputs (13 bytes a point), never the whole scan's probabilities.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.io.stream import ScanChunks, open_chunks, open_writer
from jointseg.labeller import LabelFn
from jointseg.network.backends import Predictor
from jointseg.network.choice import network_for
from jointseg.network.judge import crop_labeller
from jointseg.objects.records import LayoutReport, report_sections
from jointseg.pipeline.config import PipelineConfig
from jointseg.pipeline.tiled import frame
from jointseg.pipeline.tiled.merge import MergedScan, merge
from jointseg.pipeline.tiled.objects import TiledLayout, chunk_inputs, tiled_layout
from jointseg.pipeline.tiled.run import tile_done
from jointseg.pipeline.tiled.store import CHUNK_POINTS, TilePlan, prepare, read_plan
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TiledRun:
    """A finished tiled run: the merged outputs, the plan and the seconds of its last steps
    (the merge's ``join``, ``fusion``, ``metrics`` and ``write``)."""

    merged: MergedScan
    plan: TilePlan
    timings: dict[str, float]
    strays: int = 0
    layout: LayoutReport | None = None

    def report(self, config: PipelineConfig, timings: dict[str, float]) -> dict[str, Any]:
        """The run's report with ``timings`` (the caller's, whole-run), with the same keys as
        an untiled run's plus ``tiles``."""
        merged, plan = self.merged, self.plan
        return {
            "points": plan.points,
            "segments": merged.n_segments,
            "labels_changed": merged.labels_changed,
            "segments_split": None,
            "segments_kept": None,
            "timings_s": timings,
            "steps_s": {"tiles": merged.tile_timings},
            "params": {
                "quality": config.quality,
                "geometry": plan.geometry.model_dump(),
                "fusion": config.fusion.model_dump(),
                "network": _network_params(config, plan),
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
            "frame": None
            if plan.frame is None
            else {**plan.frame["report"], "stray_points": self.strays},
            "metrics": None
            if merged.metrics is None
            else {name: m.model_dump() for name, m in merged.metrics.items()},
            **report_sections(self.layout),
        }


def _network_params(config: PipelineConfig, plan: TilePlan) -> dict[str, Any]:
    """The network settings with what an untiled report adds: the networks that ran (several
    for an ensemble) and RandLA-Net's test-time views."""
    networks = plan.networks or [config.network.name]
    section = getattr(config.network, "randlanet", None)  # a backend section (dynamic field)
    views = getattr(section, "views", 1) if networks[0] == "randlanet" else 1
    return {**config.network.model_dump(mode="json"), "networks": networks, "views": views}


class TileProgress:
    """Progress of one tile's stages as a fraction of all tiles (``(i + f) / n``), so a bar
    per stage runs once from 0 to 1 over the whole scan."""

    def __init__(self, progress: ProgressFn | None, index: int, count: int) -> None:
        self.progress = progress
        self.index = index
        self.count = count

    def __call__(self, stage: str, fraction: float) -> None:
        report(self.progress, stage, (self.index + fraction) / self.count)


def plan(
    source: Path,
    workdir: Path,
    config: PipelineConfig,
    *,
    name: str,
    predictor: Predictor,
    max_points: int,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> TilePlan:
    """Spill ``source`` into ``workdir`` (empty or missing) and plan its tiles with the run's
    tile, geometry and seed settings; the network takes part (a crop plan shared by the tiles,
    so the tiles together label the scan as one run would).

    ``name`` is the scan's name for the plan and messages; progress stages ``read``, ``plan``.

    Raises
    ------
    ScanFormatError, ConfigError, Cancelled
    """

    def judge_for(usable: bool) -> LabelFn | None:
        return crop_labeller(network_for(predictor, config.network.choice(), usable))

    decided, bulk = frame.decide(source, config.frame, max_points, judge_for)
    log.info("%s", decided["summary"])
    stream = frame.StreamFrame(decided, bulk)
    predictor = network_for(predictor, config.network.choice(), stream.colour_usable)
    with open_chunks(source, max_points=max_points) as chunks:
        tracked = frame.Tracked(iter(chunks.chunks(CHUNK_POINTS)), stream)
        return prepare(
            iter(tracked),
            chunks.count,
            workdir,
            source=name,
            tiles=config.tiles,
            geometry=config.geometry,
            seed=config.seed,
            predictor=predictor,
            progress=progress,
            cancel=cancel,
            frame=tracked.entry,
        )


def finish(
    workdir: Path,
    config: PipelineConfig,
    source: Path,
    output: Path,
    *,
    max_points: int,
    plan: TilePlan | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> TiledRun:
    """Join the tiles of ``workdir`` (all run), vote, score, and stream ``source`` again into
    ``output`` with the pipeline's fields. Progress stages ``join``, ``fusion``, ``write``.

    Raises
    ------
    ConfigError
        When a tile has no result.
    ScanFormatError, Cancelled
    """
    plan = plan or read_plan(workdir)
    missing = [box.index for box in plan.tiles if not tile_done(workdir, box.index)]
    if missing:
        raise ConfigError(
            f"tiles {missing} are marked done but have no result in the data directory "
            f"(do all workers share it?)"
        )
    merged = merge(workdir, config, plan=plan, progress=progress, cancel=cancel)
    check_cancel(cancel)
    timings = dict(merged.timings)
    t = time.perf_counter()
    layout = _layout(source, merged, plan, config, max_points) if config.objects.enabled else None
    if layout is not None:
        timings["objects"] = time.perf_counter() - t
    t = time.perf_counter()
    with open_chunks(source, max_points=max_points) as chunks:
        strays = _write_merged(chunks, merged, plan, output, layout=layout, progress=progress)
    timings["write"] = time.perf_counter() - t
    return TiledRun(merged, plan, timings, strays, None if layout is None else layout.report)


def _layout(
    source: Path, merged: MergedScan, plan: TilePlan, config: PipelineConfig, max_points: int
) -> TiledLayout | None:
    """Objects and rooms of the whole scan from one more streamed pass (see tiled.objects)."""
    stream = None if plan.frame is None else frame.StreamFrame(plan.frame)
    to_user = np.eye(4)
    if plan.frame is not None:
        to_user = np.linalg.inv(np.array(plan.frame["report"]["to_work"], dtype=np.float64))
    with open_chunks(source, max_points=max_points) as chunks:
        inputs = chunk_inputs(
            chunks.coordinates(CHUNK_POINTS), merged.fused_label, merged.fused_confidence, stream
        )
        return tiled_layout(inputs, to_user, config.objects)


def _annotated_chunks(
    chunks: Iterator[Scan],
    merged: MergedScan,
    stream: frame.StreamFrame | None,
    counts: list[int],
    layout: TiledLayout | None = None,
) -> Iterator[Scan]:
    """The input's chunks with the pipeline's fields, as :func:`annotate` gives them
    (``counts`` gets the stray points found)."""
    start = 0
    for chunk in chunks:
        stop = start + len(chunk)
        stray = np.zeros(len(chunk), dtype=bool) if stream is None else stream.stray(chunk.xyz)
        counts.append(int(stray.sum()))
        if "instance" in chunk.fields:  # as annotate does: the input's own ids kept aside
            fields = {k: v for k, v in chunk.fields.items() if k != "instance"}
            fields["instance_input"] = chunk.fields["instance"]
            chunk = Scan(
                chunk.xyz, chunk.rgb, chunk.labels, fields, chunk.source_format, chunk.meta
            )
        yield chunk.with_fields(
            network_label=merged.network_label[start:stop].astype(np.int32),
            network_confidence=merged.network_confidence[start:stop],
            segment=merged.segment[start:stop],
            fused_label=merged.fused_label[start:stop].astype(np.int32),
            fused_confidence=merged.fused_confidence[start:stop],
            stray=stray.astype(np.uint8),
            instance=_instances(chunk, merged.fused_label[start:stop], stream, stray, layout),
        )
        start = stop


def _instances(
    chunk: Scan,
    fused: np.ndarray,
    stream: frame.StreamFrame | None,
    stray: np.ndarray,
    layout: TiledLayout | None,
) -> np.ndarray:
    """A chunk's object ids (-1 for structure, strays, or without the objects stage)."""
    if layout is None:
        return np.full(len(chunk), -1, dtype=np.int32)
    work = chunk.xyz if stream is None else stream.work_xyz(chunk.xyz)
    out = layout.point_instances(work, fused)
    out[stray] = -1
    return out


def _write_merged(
    chunks: ScanChunks,
    merged: MergedScan,
    plan: TilePlan,
    output: Path,
    *,
    layout: TiledLayout | None = None,
    progress: ProgressFn | None = None,
) -> int:
    """Stream the input again, chunk by chunk, into ``output`` with the pipeline's fields;
    the number of stray points."""
    bounds = (np.array(plan.lower), np.array(plan.upper))
    decided = None
    if plan.frame is not None:
        decided = frame.StreamFrame(plan.frame)
        bounds = (np.array(plan.frame["file_lower"]), np.array(plan.frame["file_upper"]))
    counts: list[int] = []
    stream = _annotated_chunks(chunks.chunks(CHUNK_POINTS), merged, decided, counts, layout)
    first = next(stream)
    written = 0
    with open_writer(output, count=plan.points, like=first, bounds=bounds) as writer:
        for chunk in _prepend(first, stream):
            writer.write(chunk)
            written += len(chunk)
            report(progress, "write", written / plan.points)
    return sum(counts)


def _prepend(first: Scan, rest: Iterator[Scan]) -> Iterator[Scan]:
    yield first
    yield from rest
