"""The README is a front door: short, and every block marked runnable runs as written.

Blocks preceded by ``<!-- runnable -->`` are run in order as one shell session in an empty
folder, the way a reader pastes them (a service started in one block serves the next; Python
blocks go to the virtual environment's ``python``), with ``.venv/bin`` first on PATH as after
``source .venv/bin/activate``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from jointseg.io import read_scan

README = Path(__file__).resolve().parents[2] / "README.md"
BLOCK = re.compile(r"<!-- runnable -->\s*\n```(\w+)\n(.*?)\n```", re.DOTALL)


def runnable_blocks(text: str) -> list[tuple[str, str]]:
    """(language, code) of each block marked runnable, in order."""
    return [(lang, code) for lang, code in BLOCK.findall(text)]


def as_script(blocks: list[tuple[str, str]]) -> str:
    """One bash script: shell blocks as they are, Python blocks through ``python -``."""
    parts = ["set -euo pipefail", "trap 'kill $(jobs -p) 2>/dev/null || true' EXIT"]
    for lang, code in blocks:
        if lang == "bash":
            parts.append(code)
        elif lang == "python":
            parts.append(f"python - <<'PYTHON'\n{code}\nPYTHON")
        else:
            raise AssertionError(f"a runnable block in {lang!r}: only bash and python run")
    return "\n".join(parts) + "\n"


def test_readme_is_short_and_marks_its_examples() -> None:
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    langs = [lang for lang, _ in runnable_blocks(text)]
    assert langs.count("bash") >= 2 and "python" in langs
    # the two commands come first and are not run here (make test would run itself)
    assert text.index("make run") < text.index("<!-- runnable -->")


@pytest.mark.service  # the blocks start `jointseg serve`
@pytest.mark.timeout(600)
def test_readme_runnable_blocks_run_as_written(tmp_path: Path) -> None:
    script = as_script(runnable_blocks(README.read_text()))
    bin_dir = str(Path(sys.executable).parent)
    env = {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", "")}
    env.pop("JOINTSEG_API_KEYS", None)
    done = subprocess.run(
        ["bash", "-c", script], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=540
    )
    output = f"{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    assert done.returncode == 0, f"README blocks failed:\n{output}"
    # what the blocks say they make is there and holds the pipeline's fields
    segmented = read_scan(tmp_path / "room_segmented.laz")
    assert len(segmented) == 100_000
    assert {"network_label", "segment", "fused_label"} <= set(segmented.fields)
    served = read_scan(tmp_path / "room_from_service.laz")
    assert len(served) == 100_000 and "fused_label" in served.fields
    assert (tmp_path / "report.json").stat().st_size > 0
    assert '"rooms"' in (tmp_path / "objects.json").read_text()
    assert (tmp_path / "room.ifc").read_text().startswith("ISO-10303-21")
