"""`jointseg geometry`: the geometric segmentation alone, with a JSON report."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import typer

from jointseg.cli.progress_bar import progress_bar
from jointseg.config_file import load_params_file
from jointseg.io import DEFAULT_MAX_POINTS, read_scan, write_scan
from jointseg.io.atomic import atomic_open


def geometry(
    source: Path = typer.Argument(..., help="Input scan."),
    output: Path = typer.Option(..., "-o", "--output", help="Output scan with a segment field."),
    report: Path | None = typer.Option(None, "--report", help="Write a JSON report here."),
    params: Path | None = typer.Option(None, "--params", help="GeometryParams as JSON."),
    seed: int = typer.Option(0, help="RANSAC seed."),
    max_points: int = typer.Option(DEFAULT_MAX_POINTS, help="Refuse larger scans."),
) -> None:
    """Segment a scan geometrically (planes, Euclidean clusters, colour regions), levelled and in
    metres first as `jointseg segment` does (main planes are reported in that frame)."""
    from jointseg.frame.decide import decide_frame, work_scan
    from jointseg.geometry import GeometryParams, segment
    from jointseg.metrics import segment_purity

    geometry_params = load_params_file(params, GeometryParams)
    started = time.perf_counter()
    with progress_bar() as progress:
        scan = read_scan(source, max_points=max_points, progress=progress)
        read_s = time.perf_counter() - started
        frame = decide_frame(scan)
        work, index = work_scan(scan, frame)
        result = segment(work, geometry_params, progress=progress, seed=seed)
        segments, main_plane = result.segments, result.main_plane
        if index is not None:  # strays take their nearest kept point's segment
            segments, main_plane = segments[index], main_plane[index]
        out = scan.with_fields(
            segment=segments,
            main_plane=main_plane.astype(np.uint8),
            stray=frame.stray.astype(np.uint8),
        )
        write_scan(out, output, progress=progress)
    body = {
        "input": str(source),
        "points": len(scan),
        "segments": result.n_segments,
        "main_planes": [vars(p) for p in result.planes],  # in the frame's work coordinates
        "main_plane_points": int(main_plane.sum()),
        "timings_s": {"read": read_s, **result.timings, "total": time.perf_counter() - started},
        "params": result.params.model_dump(),
        "segment_purity": None
        if scan.labels is None or not (scan.labels >= 0).any()
        else segment_purity(scan.labels, segments),
        "frame": frame.report(),
    }
    if report is not None:
        with atomic_open(report) as fh:
            fh.write(json.dumps(body, indent=2).encode())
    purity = body["segment_purity"]
    typer.echo(
        f"{len(scan):,} points -> {result.n_segments:,} segments "
        f"({len(result.planes)} main planes) in {sum(result.timings.values()):.1f} s"
        + ("" if purity is None else f", segment purity {purity:.4f}"),
        err=True,
    )


def register(app: typer.Typer) -> None:
    """Add this module's commands to ``app``."""
    app.command()(geometry)
