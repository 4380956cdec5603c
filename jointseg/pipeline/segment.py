"""Segment one scan file into an output file and a report: the one path the CLI and the job
service share, so reading, timing keys, the output fields and the report cannot drift apart.

A scan above the configuration's tile size goes through the tiled steps
(:mod:`jointseg.pipeline.tiled`) in bounded memory; the decision is ``TileParams.needs_tiles``.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jointseg.io import probe_scan, read_scan, write_scan
from jointseg.metrics import SegmentationMetrics
from jointseg.network.backends import Predictor
from jointseg.network.pending import PendingPredictor, resolve
from jointseg.pipeline import tiled
from jointseg.pipeline.config import PipelineConfig
from jointseg.pipeline.outputs import annotate, report_body
from jointseg.pipeline.stages import run
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report


@dataclass(frozen=True)
class SegmentedFile:
    """What :func:`segment_file` did: the JSON-ready report, the scores against ground truth
    (None without it) and the number of tiles (None for a run on the whole scan)."""

    report: dict[str, Any]
    metrics: dict[str, SegmentationMetrics] | None
    tiles: int | None


def segment_file(
    source: Path,
    output: Path,
    config: PipelineConfig,
    *,
    predictor: Predictor,
    max_points: int,
    load_s: float = 0.0,
    names: tuple[str, str] | None = None,
    points: int | None = None,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
    workdir: Path | None = None,
) -> SegmentedFile:
    """Run the whole method on ``source`` and write ``output`` with the pipeline's fields.

    Parameters
    ----------
    source, output : Path
    config : PipelineConfig
    predictor : Predictor
        Loaded by the caller (the worker keeps it between jobs), or loading
        (:class:`~jointseg.network.pending.PendingPredictor`: its load's seconds are added to
        ``load_s``).
    max_points : int
        Refuse larger scans.
    load_s : float
        Seconds the caller spent loading the network, reported as ``load_network``.
    names : (str, str), optional
        The input's and output's names in the report (default: the paths).
    points : int, optional
        The scan's point count when the caller knows it (else the file's header is read).
    progress, cancel : optional
    workdir : Path, optional
        A tiled run's folder (about 60 bytes a point); default: a temporary folder beside
        ``output``, removed at the end.

    Raises
    ------
    ScanFormatError, ConfigError, Cancelled
    """
    input_name, output_name = names or (str(source), str(output))
    body: dict[str, Any] = {"input": input_name, "output": output_name}
    if points is None:
        points = probe_scan(source, max_points=max_points).n_points
    pending = predictor if isinstance(predictor, PendingPredictor) else None
    if config.tiles.needs_tiles(points):
        predictor = resolve(predictor)  # before the tiles' processes start
        load_s += 0.0 if pending is None else pending.load_s
        done = _tiled(source, output, config, predictor, max_points, progress, cancel, workdir)
        body.update(done.report(config, done.timings))
        body["timings_s"] = {"load_network": load_s, **body["timings_s"]}
        body["timings_s"]["total"] += load_s
        return SegmentedFile(body, done.merged.metrics, len(done.plan.tiles))
    started = time.perf_counter()
    scan = read_scan(source, max_points=max_points, progress=progress)
    read_s = time.perf_counter() - started
    result = run(scan, config, progress, cancel, predictor=predictor)
    check_cancel(cancel)
    t = time.perf_counter()
    write_scan(annotate(scan, result), output, progress=progress)
    write_s = time.perf_counter() - t
    load_s += 0.0 if pending is None else pending.load_s  # loaded beside the read and the frame
    extra = {"load_network": load_s, "read": read_s, "write": write_s}
    body.update(report_body(scan, result, extra_timings=extra))
    return SegmentedFile(body, result.metrics, None)


def _tiled(
    source: Path,
    output: Path,
    config: PipelineConfig,
    predictor: Predictor,
    max_points: int,
    progress: ProgressFn | None,
    cancel: CancelToken | None,
    workdir: Path | None,
) -> tiled.TiledRun:
    """The three tiled steps one after the other in this process; the returned run's timings
    are the whole run's (``prepare``, ``tiles``, the merge's, ``write``, ``total``)."""
    started = time.perf_counter()
    own = workdir is None
    work = Path(tempfile.mkdtemp(prefix=".jointseg-tiles-", dir=output.parent)) if own else workdir
    assert work is not None
    timings: dict[str, float] = {}
    try:
        t = time.perf_counter()
        plan = tiled.plan(
            source,
            work,
            config,
            name=source.name,
            predictor=predictor,
            max_points=max_points,
            progress=progress,
            cancel=cancel,
        )
        timings["prepare"] = time.perf_counter() - t
        t = time.perf_counter()
        for box in plan.tiles:
            check_cancel(cancel)
            tiled.run_tile(
                work,
                box.index,
                config,
                predictor=predictor,
                plan=plan,
                progress=tiled.TileProgress(progress, box.index, len(plan.tiles)),
                cancel=cancel,
            )
            report(progress, "tiles", (box.index + 1) / len(plan.tiles))
        timings["tiles"] = time.perf_counter() - t
        done = tiled.finish(
            work,
            config,
            source,
            output,
            max_points=max_points,
            plan=plan,
            progress=progress,
            cancel=cancel,
        )
        timings.update(done.timings)
    finally:
        if own:
            shutil.rmtree(work, ignore_errors=True)
    timings["total"] = time.perf_counter() - started
    return tiled.TiledRun(done.merged, done.plan, timings, done.strays, done.layout)
