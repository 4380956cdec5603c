"""What a user installs is what was tested: the wheel built from this tree holds every data file
the packages read (fitted models, bundled weights, the viewer's static files), not only the code.

A file left out is no error at install time: the up-axis weighing, for one, falls back to
placeholder weights when ``up_model.json`` is missing.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("jointseg", "server", "web")


def _tracked(*paths: str) -> list[str]:
    """The files git tracks under ``paths`` (all of them when none is given)."""
    out = subprocess.run(
        ["git", "ls-files", *paths], cwd=ROOT, check=True, capture_output=True, text=True
    ).stdout.split()
    return sorted(out)


def _fresh_copy(target: Path) -> Path:
    """The tracked tree copied to ``target``: no build/ or egg-info left from an earlier build
    can add a file the project's own settings leave out."""
    for name in _tracked():
        if (ROOT / name).is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, target / name)
    return target


def test_the_wheel_holds_every_data_file_of_the_packages(tmp_path: Path) -> None:
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the tracked files are unknown")
    data = [f for f in _tracked(*PACKAGES) if not f.endswith(".py")]
    assert "jointseg/frame/up_model.json" in data  # the list is the real one
    source = _fresh_copy(tmp_path / "src")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation",
         str(source), "-w", str(tmp_path / "dist")],
        check=True, capture_output=True,
    )  # fmt: skip
    (wheel,) = (tmp_path / "dist").glob("jointseg-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = [f for f in data if f not in names]
    assert not missing, f"the wheel lacks {missing}"
