"""`jointseg objects`: objects, rooms and an IFC model from an already segmented file, and the
writers `jointseg segment --objects/--ifc` share."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import typer

from jointseg.exceptions import ConfigError
from jointseg.io.atomic import atomic_open


def layout_from_report(body: dict[str, Any]) -> Any:
    """The layout a run's report holds (its ``objects`` and ``rooms`` sections)."""
    from jointseg.objects.records import LayoutReport

    return LayoutReport.from_report(body)


def write_layout(layout: Any, objects: Path | None, ifc: Path | None, name: str) -> str:
    """Write ``objects.json`` and the IFC model when asked; the one-line summary."""
    if objects is not None:
        with atomic_open(objects) as fh:
            fh.write(json.dumps(layout.model_dump(mode="json"), indent=1).encode())
    written = ""
    if ifc is not None:
        from jointseg.objects.ifc import write_ifc

        counts = write_ifc(layout, ifc, name=name)
        written = f"; IFC {ifc}: " + ", ".join(f"{v} {k}" for k, v in counts.items() if v)
    counts = layout.counts()
    things = ", ".join(f"{v} {k}" for k, v in counts.items() if k not in ("rooms", "walls"))
    rooms = "; ".join(
        f"{r.name} {r.floor_area:.1f} m²"
        + ("" if r.ceiling_height is None else f" x {r.ceiling_height:.2f} m")
        for r in layout.rooms
    )
    reason = f" ({layout.reason})" if layout.reason else ""
    return (
        f"objects: {things or 'none'}; rooms: {rooms or 'none'}; "
        f"{counts['walls']} walls{reason}{written}"
    )


def objects(
    source: Path = typer.Argument(..., help="A file written by `jointseg segment` (fused_label)."),
    objects_out: Path | None = typer.Option(
        None, "--objects", help="Write objects.json (objects, rooms, walls) here."
    ),
    ifc: Path | None = typer.Option(None, "--ifc", help="Write an IFC4 model here."),
    up: str | None = typer.Option(None, "--up", help="auto, +z, -z, +y, -y, +x or -x."),
    units: str | None = typer.Option(None, "--units", help="auto, m, cm, mm, ft, us-ft or in."),
) -> None:
    """Objects, rooms, walls, doors and windows (and an IFC model) from a segmented scan."""
    import numpy as np

    from jointseg.frame.decide import decide_frame
    from jointseg.frame.params import FrameParams
    from jointseg.io import read_scan
    from jointseg.objects.layout import find_layout
    from jointseg.spacing import estimate_spacing

    scan = read_scan(source)
    if "fused_label" not in scan.fields:
        raise ConfigError(f"{source}: no fused_label field; run `jointseg segment` on it first")
    settings: dict[str, str] = {}
    if up is not None:
        settings["up"] = up
    if units is not None:
        settings["units"] = units
    frame = decide_frame(scan, FrameParams.model_validate(settings))
    work = frame.to_work(scan.xyz)
    keep = ~frame.stray
    confidence = scan.fields.get("fused_confidence")
    layout = find_layout(
        work[keep],
        np.asarray(scan.fields["fused_label"])[keep],
        None if confidence is None else np.asarray(confidence)[keep],
        estimate_spacing(work[keep]),
        to_user=np.linalg.inv(np.asarray(frame.matrix())),
    ).report
    typer.echo(write_layout(layout, objects_out, ifc, source.stem), err=True)


def register(app: typer.Typer) -> None:
    """Add this module's commands to ``app``."""
    app.command()(objects)
