"""`jointseg serve --help` and `jointseg worker --help` name every option's default (issue 45,
point 2), the defaults are the settings' own, and an option left out leaves the environment's
value alone while a typed one overrides it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from jointseg.cli.app import app
from server.settings import Settings

JOINTSEG = str(Path(sys.executable).parent / "jointseg")
#: The options of each command and the setting each one sets.
OPTIONS = {
    "serve": {"--host": "host", "--port": "port", "--viewer-port": "viewer_port",
              "--data-dir": "data_dir", "--workers": "workers"},
    "worker": {"--data-dir": "data_dir"},
}  # fmt: skip


def _help(command: str) -> str:
    # wide and without colour, so each option's help is on one line, as plain text
    result = CliRunner().invoke(app, [command, "--help"], env={"COLUMNS": "300", "NO_COLOR": "1"})
    assert result.exit_code == 0, result.output
    return result.output


def _option_help(text: str, option: str) -> str:
    """The help row of ``option`` (the line that starts with it, up to the next option)."""
    match = re.search(rf"│ {re.escape(option)} .*?(?=│ --|╰)", text, re.S)
    assert match, f"{option} not in the help:\n{text}"
    return match.group(0)


@pytest.mark.parametrize("command", sorted(OPTIONS))
def test_every_option_names_its_default_and_variable(command: str) -> None:
    text = _help(command)
    for option, field in OPTIONS[command].items():
        row = _option_help(text, option)
        default: Any = Settings.model_fields[field].default
        assert f"[default: {default}]" in row, row
        assert f"JOINTSEG_{field.upper()}" in row, row
    assert " . " not in text and "address ." not in text  # no help text lost to markup
    assert "[default: 127.0.0.1]" in text or command == "worker"


def test_the_serve_help_shows_the_defaults_a_user_expects() -> None:
    text = _help("serve")
    for expected in ("127.0.0.1", "8000", "8080", "[default: data]", "[default: 1]"):
        assert expected in text, text


def _serve(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """`jointseg serve ARGS` as a user runs it, with only ``env`` of the JOINTSEG_ variables."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("JOINTSEG_")}
    return subprocess.run(
        [JOINTSEG, "serve", *args], env=clean | env, capture_output=True, text=True, timeout=60
    )


def test_options_left_out_keep_the_environment_and_typed_ones_override_it() -> None:
    # settings are checked before anything starts: an invalid value stops serve at once
    left_out = _serve(JOINTSEG_WORKERS="-1")
    assert left_out.returncode == 2, left_out.stderr
    # the default 1 shown in --help did not replace the environment's -1
    assert "invalid settings: workers" in left_out.stderr, left_out.stderr
    typed = _serve("--workers", "1", "--port", "99999", JOINTSEG_WORKERS="-1")
    assert typed.returncode == 2, typed.stderr
    assert "invalid settings: port" in typed.stderr and "workers" not in typed.stderr
