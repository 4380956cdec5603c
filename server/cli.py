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


def given(ctx: typer.Context, **values: Any) -> dict[str, Any]:
    """The options typed on the command line, by name.

    Why: the options show the settings' defaults in ``--help``, but an option left out must
    not override what the environment or JOINTSEG_CONFIG says, so only the typed ones go to
    :func:`load_settings`.
    """
    # by the source's name: typer carries its own copy of click, whose enum is not click's
    sources = {name: getattr(ctx.get_parameter_source(name), "name", None) for name in values}
    return {name: value for name, value in values.items() if sources[name] == "COMMANDLINE"}


def _setting(default: Any, text: str, variable: str) -> Any:
    """An option whose help names the setting's default and its environment variable.

    The default is written out (this module must not import :class:`server.settings.Settings`:
    see the module doc); a test holds each to Settings'.
    """
    return typer.Option(default, help=f"{text}; when not given: {variable} or JOINTSEG_CONFIG.")


def serve(
    ctx: typer.Context,
    host: str = _setting("127.0.0.1", "Address the API listens on", "JOINTSEG_HOST"),
    port: int = _setting(8000, "Port of the API and the job page", "JOINTSEG_PORT"),
    viewer_port: int = _setting(8080, "Port of the viewer", "JOINTSEG_VIEWER_PORT"),
    data_dir: Path = _setting(Path("data"), "Uploads, results, job table", "JOINTSEG_DATA_DIR"),
    workers: int = _setting(1, "Worker processes to start", "JOINTSEG_WORKERS"),
    viewer: bool = typer.Option(True, help="Also run the viewer and the job page (web/)."),
) -> None:
    """Run the job service: the API, the worker processes and the viewer (Ctrl-C stops all)."""
    settings = load_settings(
        **given(
            ctx, host=host, port=port, viewer_port=viewer_port, data_dir=data_dir, workers=workers
        )
    )
    from server.metrics import use_folder

    use_folder(settings.data_dir)  # before anything imports prometheus_client
    # deferred: the API stack (FastAPI, uvicorn, SQLAlchemy, Huey); see the module doc
    from server.serve_parts import ServeParts, load_serve_parts
    from server.service import run_service

    parts = load_serve_parts() if viewer else ServeParts([], [])
    run_service(settings, extra_routers=parts.routers, extra_processes=parts.processes)


def worker(
    ctx: typer.Context,
    data_dir: Path = _setting(Path("data"), "The API's data directory", "JOINTSEG_DATA_DIR"),
) -> None:
    """Run one worker process (any number, on any machine sharing the data directory)."""
    settings = load_settings(**given(ctx, data_dir=data_dir))
    from server.metrics import use_folder

    use_folder(settings.data_dir)  # before anything imports prometheus_client
    # deferred: the worker stack (SQLAlchemy, Huey, the pipeline); see the module doc
    from server.worker.process import worker_main

    worker_main(settings)


def register(app: typer.Typer) -> None:
    """Entry point of the ``jointseg.commands`` group: add serve and worker to ``app``."""
    app.command("serve")(serve)
    app.command("worker")(worker)
