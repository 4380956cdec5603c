"""The ``jointseg`` command as a user starts it: the real entry point in a new Python process,
shared by every test that checks what the command prints and the files it writes."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path


def run_cli(
    *args: str,
    cwd: Path | None = None,
    env: Mapping[str, str] | None = None,
    unset: Iterable[str] = (),
    timeout: float = 300,
) -> subprocess.CompletedProcess[str]:
    """``python -m jointseg *args``, its output captured as text.

    Parameters
    ----------
    cwd : Path, optional
        Folder to run in (relative paths in ``args`` are read from there).
    env : mapping, optional
        Variables set over this process's environment.
    unset : iterable of str
        Variables of this process's environment the command must not see.
    timeout : float
        Seconds before the command is killed (and the test fails).
    """
    dropped = set(unset)
    environment = {k: v for k, v in os.environ.items() if k not in dropped}
    return subprocess.run(
        [sys.executable, "-m", "jointseg", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=cwd,
        env={**environment, **(env or {})},
    )
