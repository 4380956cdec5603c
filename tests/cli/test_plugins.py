"""Commands from the `jointseg.commands` entry-point group: server's serve and worker are there,
and a broken plugin is skipped with a warning instead of breaking the CLI."""

from __future__ import annotations

import logging

import typer
from typer.testing import CliRunner

from jointseg.cli.app import PLUGIN_GROUP, app, load_plugins


def test_server_commands_come_from_the_entry_point() -> None:
    names = {command.name for command in app.registered_commands}
    assert {"serve", "worker", "submit", "segment"} <= names
    result = CliRunner().invoke(app, ["serve", "--help"])
    assert result.exit_code == 0 and "--workers" in result.output
    assert "--viewer-port" in result.output and "--data-dir" in result.output


def test_a_broken_plugin_does_not_break_the_cli(tmp_path, monkeypatch, caplog) -> None:
    dist = tmp_path / "broken_plugin-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-plugin\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(
        f"[{PLUGIN_GROUP}]\nbroken = no_such_module_anywhere:register\ngood = server.cli:register\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    target = typer.Typer()
    with caplog.at_level(logging.WARNING):
        loaded = load_plugins(target)
    assert "good" in loaded and "broken" not in loaded
    assert {"serve", "worker"} <= {c.name for c in target.registered_commands}
    assert "skipping command plugin 'broken'" in caplog.text
    assert "No module named 'no_such_module_anywhere'" in caplog.text
