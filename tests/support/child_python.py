"""Run a snippet in a fresh interpreter with a cache folder of its own: how the tests that load
OpenVINO keep its thread pools out of the test process (they do not survive the forks other
tests make) and start each case from a known cache."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any


def in_child(code: str, cache: Path, *args: str) -> dict[str, Any]:
    """Run ``code`` in a fresh interpreter with ``JOINTSEG_CACHE=cache``; its last JSON line."""
    env = {**os.environ, "JOINTSEG_CACHE": str(cache)}
    done = subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        env=env, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result
