"""`jointseg relabel`: a result's labels corrected by an edit list, written as a new result
(``fused_label`` the corrected class, ``user_label`` what the user gave), with its objects, IFC
and report made from the corrected labels, as the job service makes a labels version's."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from jointseg.exceptions import ConfigError

EDITS_HELP = (
    'JSON edit list: {"edits": [{"segments": [ids], "label": "wall"}, {"points": [indices], '
    '"label": 7}, {"box": {"min": [x, y, z], "max": [x, y, z]}, "label": "table"}]}.'
)


def read_json(path: Path, what: str) -> object:
    """A JSON file an option names; a clear ConfigError naming the option when it is missing
    or not JSON."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{what} {path}: no such file") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{what} {path}: not valid JSON ({exc})") from None


def relabel(
    result: Path = typer.Argument(..., help="A file written by `jointseg segment`."),
    edits: Path = typer.Option(..., "--edits", help=EDITS_HELP),
    out: Path = typer.Option(..., "-o", "--out", help="The corrected result (ply, las, laz)."),
    report: Path | None = typer.Option(
        None, "--report", help="The run's report.json: its frame places the objects as the run did."
    ),
    report_out: Path | None = typer.Option(
        None, "--report-out", help="Write the corrected result's report here."
    ),
    objects_out: Path | None = typer.Option(
        None, "--objects", help="Write the corrected objects.json here."
    ),
    ifc: Path | None = typer.Option(None, "--ifc", help="Write the corrected IFC4 model here."),
) -> None:
    """Correct a result's labels by segment, point or box; every output follows the edits."""
    from jointseg.cli.objects_command import write_layout
    from jointseg.cli.pipeline_commands import FIELD_EXTENSIONS
    from jointseg.io import read_scan, write_scan
    from jointseg.io.atomic import atomic_open
    from jointseg.labels.edits import apply_edits, parse_edits
    from jointseg.labels.version import (
        check_result,
        machine_labels,
        user_labels_of,
        version_outputs,
    )

    if out.suffix.lower() not in FIELD_EXTENSIONS:
        raise ConfigError(f"--out {out}: use one of {', '.join(FIELD_EXTENSIONS)} (keeps fields)")
    edit_list = parse_edits(read_json(edits, "--edits"))
    run_report = None if report is None else read_json(report, "--report")
    if run_report is not None and not isinstance(run_report, dict):
        raise ConfigError(f"--report {report}: not a report (a JSON object)")
    scan = read_scan(result)
    check_result(scan, name=str(result))
    outcome = apply_edits(
        edit_list,
        machine_labels=machine_labels(scan),
        user_label=user_labels_of(scan),
        segment=scan.fields["segment"],
        xyz=scan.xyz,
    )
    before = (run_report or {}).get("labels") or {}
    labelled, layout, body = version_outputs(
        scan,
        outcome.user_label,
        run_report,
        version=int(before.get("version", 0)) + 1,
        objects=objects_out is not None or ifc is not None or report_out is not None,
    )
    write_scan(labelled, out)
    summary = f"{outcome.changed:,} labels changed by {len(edit_list.edits)} edits; {out}"
    if report_out is not None:
        with atomic_open(report_out) as fh:
            fh.write(json.dumps(body, indent=1).encode())
    if layout is not None and (objects_out is not None or ifc is not None):
        summary += "\n" + write_layout(layout.report, objects_out, ifc, out.stem)
    typer.echo(summary, err=True)


def register(app: typer.Typer) -> None:
    """Add this module's commands to ``app``."""
    app.command()(relabel)
