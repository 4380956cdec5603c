"""`jointseg serve` and `jointseg worker`, added to the jointseg CLI through the entry-point
group ``jointseg.commands`` (jointseg itself never imports server).

This module is imported by every ``jointseg`` command (to register these two), so everything
the service needs (FastAPI, SQLAlchemy, Huey, uvicorn) is imported only when one of them runs.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from jointseg.exceptions import ConfigError

if TYPE_CHECKING:
    from server.settings import Settings


def load_settings(**overrides: Any) -> Settings:
    """Settings from the environment / JOINTSEG_CONFIG with the command line's options on top.

    Raises
    ------
    ConfigError
        Naming the setting that is invalid.
    """
    # deferred: pydantic-settings is only needed once serve or worker runs (see module doc)
    from pydantic import ValidationError

    from server.settings import Settings

    given = {k: v for k, v in overrides.items() if v is not None}
    try:
        return Settings(**given)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'settings'}: {e['msg']}" for e in exc.errors()
        )
        raise ConfigError(f"invalid settings: {problems}") from exc
    except ValueError as exc:  # e.g. JOINTSEG_CONFIG names a missing file
        raise ConfigError(str(exc)) from exc


def serve(
    host: str | None = typer.Option(None, help="API address [default: 127.0.0.1]."),
    port: int | None = typer.Option(None, help="API port [default: 8000]."),
    viewer_port: int | None = typer.Option(None, help="Viewer port [default: 8080]."),
    data_dir: Path | None = typer.Option(None, help="Data directory [default: ./data]."),
    workers: int | None = typer.Option(None, help="Worker processes [default: 1]."),
    viewer: bool = typer.Option(True, help="Also run the viewer and the job page (web/)."),
) -> None:
    """Run the job service: the API, the worker processes and the viewer (Ctrl-C stops all)."""
    settings = load_settings(
        host=host, port=port, viewer_port=viewer_port, data_dir=data_dir, workers=workers
    )
    # deferred: the API stack (FastAPI, uvicorn, SQLAlchemy, Huey); see the module doc
    from server.serve_parts import ServeParts, load_serve_parts
    from server.service import run_service

    parts = load_serve_parts() if viewer else ServeParts([], [])
    run_service(settings, extra_routers=parts.routers, extra_processes=parts.processes)


def worker(
    data_dir: Path | None = typer.Option(None, help="Data directory [default: ./data]."),
) -> None:
    """Run one worker process (any number, on any machine sharing the data directory)."""
    settings = load_settings(data_dir=data_dir)
    # deferred: the worker stack (SQLAlchemy, Huey, the pipeline); see the module doc
    from server.worker.process import worker_main

    worker_main(settings)


def register(app: typer.Typer) -> None:
    """Entry point of the ``jointseg.commands`` group: add serve and worker to ``app``."""
    app.command("serve")(serve)
    app.command("worker")(worker)
