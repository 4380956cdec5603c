"""`jointseg synth`, `jointseg info` and `jointseg convert`: making and inspecting scans."""

from __future__ import annotations

import json
import logging
import time
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer
from rich.console import Console
from rich.table import Table

from jointseg.cli.progress_bar import progress_bar
from jointseg.io import READ_EXTENSIONS, read_scan, write_scan

if TYPE_CHECKING:  # the summary loads scipy's KD-tree, which `jointseg --help` does not need
    from jointseg.summary import ScanSummary

DEFAULT_MAX_POINTS = 50_000_000
#: What an input argument accepts, from the formats table (meshes are sampled to points).
SCAN_HELP = (
    f"Scan file ({', '.join(READ_EXTENSIONS)}; meshes are sampled to points) or S3DIS room folder."
)
stdout_console = Console(highlight=False)


class RoomShape(StrEnum):
    """The plan of a synthetic room: a rectangle, or an L (a rectangle with one corner cut out)."""

    box = "box"
    L = "L"


def synth(
    output: Path = typer.Option(..., "-o", "--output", help="Output scan (.ply, .las, .laz, ...)."),
    seed: int = typer.Option(0, help="Random seed; the same seed gives the same scan."),
    points: int = typer.Option(1_000_000, help="Number of points."),
    shape: RoomShape = typer.Option(RoomShape.box, help="Room footprint."),
    yaw: float | None = typer.Option(None, help="Rotation about z in degrees (default: random)."),
    floor: int = typer.Option(
        0, help="Generate a whole floor with this many rooms and a corridor instead of one room."
    ),
) -> None:
    """Generate a synthetic S3DIS-style room (or floor) with ground-truth labels."""
    from jointseg.synth import make_floor, make_room

    started = time.perf_counter()
    with progress_bar() as progress:
        if floor:
            scan = make_floor(seed, rooms=floor, points=points, yaw=yaw, progress=progress)
        else:
            scan = make_room(seed, points=points, shape=shape.value, yaw=yaw, progress=progress)
        write_scan(scan, output, progress=progress)
    typer.echo(
        f"wrote {len(scan):,} points to {output} in {time.perf_counter() - started:.1f} s",
        err=True,
    )


def info(
    path: Path = typer.Argument(..., help=SCAN_HELP),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
    max_points: int = typer.Option(DEFAULT_MAX_POINTS, help="Refuse larger scans."),
) -> None:
    """Describe a scan: points, bounds, spacing, fields and label histogram."""
    with progress_bar(enabled=not as_json) as progress:
        scan = read_scan(path, max_points=max_points, progress=progress)
    from jointseg.summary import summarise

    summary = summarise(scan)
    frame = _frame_of(scan)
    if as_json:
        typer.echo(json.dumps({**summary.model_dump(), "frame": frame}, indent=2))
        return
    metres = 1.0 if frame is None else float(frame["units"]["metres_per_unit"])
    _print_summary(path, summary, metres)
    if frame is not None:
        from jointseg.frame.decide import summary_line

        stdout_console.print(summary_line(frame), markup=False, highlight=False)
        for warning in frame["warnings"]:
            stdout_console.print(f"warning: {warning}", markup=False, highlight=False)


def _frame_of(scan: Any) -> dict[str, Any] | None:
    """What the frame stage of ``jointseg segment`` would decide for the scan, the default
    network judging the likeliest up axes as it does there (None for a scan too small to
    place)."""
    from jointseg.exceptions import ConfigError
    from jointseg.frame.decide import decide_frame

    if len(scan) < 20:
        return None
    try:
        return decide_frame(scan, judge=_default_judge(scan)).report()
    except ConfigError:
        return None


def _default_judge(scan: Any) -> Any:
    """The default network (colour-free for a scan without usable colour) as the frame's
    judge, loaded only when the frame stage asks it (a scan whose file and geometry agree
    never loads torch); None, with a log line, when its weights are not installed."""
    from jointseg.frame.colour import decide_colour
    from jointseg.network.registry import resolve_weights
    from jointseg.pipeline import PipelineConfig

    config = PipelineConfig()
    weights = resolve_weights(config.network.name, config.network.weights)
    if weights is None or not weights.is_file():
        logging.getLogger(__name__).info("no network to judge the up axis (%s)", weights)
        return None
    usable = decide_colour(scan.rgb, config.frame.colour).usable
    loaded: list[Any] = []

    def label(xyz: Any, rgb: Any) -> Any:
        if not loaded:
            from jointseg.network.choice import network_for
            from jointseg.network.judge import crop_labeller
            from jointseg.pipeline import load_predictor

            predictor = load_predictor(config.network)
            loaded.append(crop_labeller(network_for(predictor, config.network.choice(), usable)))
        return loaded[0](xyz, rgb)

    return label


def convert(
    source: Path = typer.Argument(..., help=SCAN_HELP),
    target: Path = typer.Argument(..., help="Output scan; the format follows the extension."),
    max_points: int = typer.Option(DEFAULT_MAX_POINTS, help="Refuse larger scans."),
) -> None:
    """Convert a scan between formats, keeping colour, labels and every field."""
    with progress_bar() as progress:
        scan = read_scan(source, max_points=max_points, progress=progress)
        write_scan(scan, target, progress=progress)
    typer.echo(f"wrote {len(scan):,} points to {target}", err=True)


def _print_summary(path: Path, s: ScanSummary, metres: float = 1.0) -> None:
    """The summary as text; ``metres`` per file unit (the frame stage's decision) for the
    spacing, which users read in millimetres."""
    out = stdout_console
    out.print(f"[bold]{path}[/bold] ({s.source_format})")
    out.print(f"points   {s.points:,}")
    lo = ", ".join(f"{v:.3f}" for v in s.bounds_min)
    hi = ", ".join(f"{v:.3f}" for v in s.bounds_max)
    ext = " x ".join(f"{v:.2f}" for v in s.extent)
    out.print(f"bounds   ({lo}) .. ({hi}) (file units)")
    out.print(f"extent   {ext} (file units)")
    out.print(f"spacing  {s.spacing * metres * 1000:.1f} mm (median nearest-neighbour distance)")
    out.print(f"colour   {'yes' if s.has_rgb else 'no'}")
    if s.fields:
        table = Table("field", "dtype", "width", "min", "max", title="fields")
        for f in s.fields:
            table.add_row(f.name, f.dtype, str(f.width), f"{f.min:.4g}", f"{f.max:.4g}")
        out.print(table)
    if s.label_histogram is None:
        out.print("labels   none")
        return
    table = Table("label", "points", "share", title="labels")
    total = sum(s.label_histogram.values()) or 1
    for name, count in s.label_histogram.items():
        table.add_row(name, f"{count:,}", f"{100 * count / total:.1f}%")
    out.print(table)


def register(app: typer.Typer) -> None:
    """Add this module's commands to ``app``."""
    app.command()(synth)
    app.command()(info)
    app.command()(convert)
