"""Typer application: error handling shared by every command.

Errors a user can cause (a bad file, a bad parameter) print one line and exit with status 2;
anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import logging
import sys
from importlib.metadata import entry_points

import typer
from rich.markup import escape

from jointseg.cli import (
    adapt_command,
    client_commands,
    fit_commands,
    geometry_command,
    network_commands,
    objects_command,
    pipeline_commands,
    relabel_command,
    scan_commands,
)
from jointseg.cli.progress_bar import stderr_console
from jointseg.exceptions import JointsegError

app = typer.Typer(
    name="jointseg",
    help="Semantic segmentation of indoor 3D scans (network + geometry + fusion).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
scan_commands.register(app)
geometry_command.register(app)
network_commands.register(app)
objects_command.register(app)
pipeline_commands.register(app)
relabel_command.register(app)
adapt_command.register(app)
client_commands.register(app)
fit_commands.register(app)

#: Entry-point group through which other packages add commands (server: serve, worker); each
#: entry point is a callable ``register(app: typer.Typer)``.
PLUGIN_GROUP = "jointseg.commands"
log = logging.getLogger(__name__)


def load_plugins(target: typer.Typer, group: str = PLUGIN_GROUP) -> list[str]:
    """Register the commands of every installed plugin; a broken one is skipped with a warning.

    Returns
    -------
    list of str
        Names of the entry points that registered.
    """
    loaded = []
    for ep in entry_points(group=group):
        try:
            ep.load()(target)
        except Exception as exc:  # noqa: BLE001 - one broken plugin must not break the CLI
            log.warning("jointseg: skipping command plugin %r (%s): %s", ep.name, ep.value, exc)
            continue
        loaded.append(ep.name)
    return loaded


load_plugins(app)


@app.callback()
def _root(
    verbose: bool = typer.Option(False, "--verbose", "-v", help="Log progress details."),
) -> None:
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script."""
    try:
        app(args=argv, standalone_mode=True)
    except JointsegError as exc:
        stderr_console.print(
            f"[red]error:[/red] {escape(str(exc))}", highlight=False, soft_wrap=True
        )
        sys.exit(2)
