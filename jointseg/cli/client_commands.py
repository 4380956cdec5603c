"""`jointseg submit`: send a scan to a job service and (optionally) wait for and fetch the result.

The "poll from scripts" use of the service: the job id goes to stdout, progress to stderr.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

from jointseg.cli.progress_bar import progress_bar
from jointseg.client import API_KEY_ENV, RESULT_SUFFIXES, JobClient
from jointseg.exceptions import ConfigError
from jointseg.io.atomic import atomic_open


def submit_scan(
    source: Path = typer.Argument(..., help="Scan to upload (any format jointseg reads)."),
    server: str = typer.Option(
        "http://127.0.0.1:8000", "--server", envvar="JOINTSEG_SERVER", help="Job service URL."
    ),
    wait: bool = typer.Option(False, "--wait", help="Wait for the job, showing its progress."),
    output: Path | None = typer.Option(
        None, "-o", "--output", help="Save the result here (.ply, .las, .laz); implies --wait."
    ),
    report: Path | None = typer.Option(
        None, "--report", help="Save the job's report.json here; implies --wait."
    ),
    config: Path | None = typer.Option(
        None, "--config", help="PipelineConfig JSON file sent with the scan."
    ),
    api_key: str | None = typer.Option(
        None, "--api-key", envvar=API_KEY_ENV, help="API key, when the service needs one."
    ),
    timeout: float | None = typer.Option(None, help="Give up waiting after this many seconds."),
) -> None:
    """Submit a scan to a jointseg job service; print the job id."""
    if output is not None and output.suffix.lower() not in RESULT_SUFFIXES:
        raise ConfigError(f"{output}: results are {', '.join(RESULT_SUFFIXES)} files")
    for path in (output, report):
        if path is not None and not path.parent.is_dir():
            raise ConfigError(f"{path}: folder {path.parent} does not exist")
    body = None
    if config is not None:
        try:
            body = json.loads(config.read_text())
        except (OSError, ValueError) as exc:
            raise ConfigError(f"--config {config}: {exc}") from exc
    with JobClient(server, api_key=api_key) as client:
        job = client.submit(source, config=body)
        typer.echo(job.id)
        if not (wait or output or report):
            return
        with progress_bar() as progress:
            job = client.wait(job.id, progress=progress, timeout_s=timeout)
        line = f"job {job.id} succeeded: {job.points or 0:,} points"
        if job.timings:
            line += f" in {job.timings.get('total', 0.0):.1f} s"
        if output is not None:
            client.download(job.id, output)
            line += f" -> {output}"
        if report is not None:
            with atomic_open(report) as fh:
                fh.write(json.dumps(client.report(job.id), indent=2).encode())
        typer.echo(line, err=True)


def register(app: typer.Typer) -> None:
    """Add this module's commands to ``app``."""
    app.command("submit")(submit_scan)
