"""What a user installs is what was tested: the wheel built from this tree holds every data file
the packages read (fitted models, bundled weights, the viewer's static files), not only the code,
and the installed package segments a scan as the checkout does.

A file left out is no error at install time: before issue 46 the up-axis weighing fell back to
zero and placeholder weights when ``up_model.json`` was missing, and turned scans by chance.

And what the packages need is declared (issue 69): every module they import is a dependency of
their own (deptry; a module that only comes with another package goes when that package stops
needing it), and the model cards they ship name no folder of the machine they were made on.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from collections.abc import Sequence
from pathlib import Path
from subprocess import CompletedProcess
from typing import Any

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("jointseg", "server", "web")
#: The synthetic room the installed package segments: small, fixed seed and yaw.
ROOM_POINTS, ROOM_SEED = 60_000, 0
#: One-liners run by the installed python: where its packages come from, where it installs.
WHERE = "import jointseg, server, web; print(jointseg.__file__, server.__file__, web.__file__)"
PURELIB = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
#: Data files of the installed package, and the code that reads each (the loaders the pipeline
#: calls on the default paths).
SHIPPED = ("frame/up_model.json", "fusion/vote_model.json", "network/weights/randlanet_indoor.pt")
LOADERS = (
    "from jointseg.frame import gravity; gravity.model_weights()",
    "from jointseg.fusion.tree_runtime import shipped_model; shipped_model()",
    "from jointseg.network.registry import load; load('randlanet')",
)


def _source_files(*paths: str) -> list[str]:
    """The files of the source tree under ``paths`` (all when none is given), as in the working
    tree: those git tracks and those it would add (untracked, not ignored), so the wheel is built
    from the same tree the checkout's run uses, work not yet added included. Ignored leftovers
    (build/, egg-info) are not among them."""
    command = ["git", "ls-files", "--cached", "--others", "--exclude-standard", *paths]
    listed = subprocess.run(command, cwd=ROOT, check=True, capture_output=True, text=True)
    return sorted({name for name in listed.stdout.splitlines() if (ROOT / name).is_file()})


def _fresh_copy(target: Path) -> Path:
    """The source tree copied to ``target``: no build/ or egg-info left from an earlier build
    can add a file the project's own settings leave out."""
    for name in _source_files():
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, target / name)
    return target


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel built from a fresh copy of the source tree, once for this module's tests."""
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout: the source files are unknown")
    tmp = tmp_path_factory.mktemp("wheel")
    source = _fresh_copy(tmp / "src")
    build = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation"]
    subprocess.run([*build, str(source), "-w", str(tmp / "dist")], check=True, capture_output=True)
    (built,) = (tmp / "dist").glob("jointseg-*.whl")
    return built


@pytest.mark.slow  # a wheel built and installed: minutes, not for `make test-fast`
def test_the_wheel_holds_every_data_file_of_the_packages(wheel: Path) -> None:
    data = [f for f in _source_files(*PACKAGES) if not f.endswith(".py")]
    assert "jointseg/frame/up_model.json" in data  # the list is the real one
    names = set(zipfile.ZipFile(wheel).namelist())
    missing = [f for f in data if f not in names]
    assert not missing, f"the wheel lacks {missing}"


def _clean_env() -> dict[str, str]:
    """The environment without anything that would put the checkout on sys.path or choose
    other weights than the bundled ones (the tests' throw-away cache is kept)."""
    drop = ("PYTHONPATH", "PYTHONHOME", "PYTHONSTARTUP")
    return {
        k: v
        for k, v in os.environ.items()
        if k not in drop and not (k.startswith("JOINTSEG_") and k != "JOINTSEG_CACHE")
    }


def _call(args: Sequence[object], cwd: Path, env: dict[str, str]) -> CompletedProcess[str]:
    """``args`` run in ``cwd`` with ``env``, its output captured as text."""
    line = [str(a) for a in args]
    return subprocess.run(line, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def _run(args: Sequence[object], cwd: Path, env: dict[str, str]) -> str:
    """The stdout of ``args``, or a failure showing its stderr."""
    done = _call(args, cwd, env)
    assert done.returncode == 0, f"{[str(a) for a in args]} failed:\n{done.stderr[-3000:]}"
    return done.stdout


def _fresh_venv(where: Path, wheel: Path, env: dict[str, str]) -> Path:
    """A new virtual environment with ``wheel`` installed and nothing else of the checkout; its
    python. The heavy dependencies (torch, open3d, ...) come from this interpreter's
    site-packages through a plain path line in a .pth file: it adds the folder to sys.path
    without running the .pth files inside it (the editable install's finder among them)."""
    try:
        venv = [sys.executable, "-m", "venv", "--without-pip", str(where)]
        subprocess.run(venv, check=True, capture_output=True, timeout=120)
    except (OSError, subprocess.SubprocessError) as exc:
        pytest.skip(f"cannot create a virtual environment here: {exc}")
    python = where / "bin" / "python"
    purelib = _run([python, "-c", PURELIB], where, env).strip()
    (Path(purelib) / "checkout_dependencies.pth").write_text(sysconfig.get_paths()["purelib"])
    pip = [sys.executable, "-m", "pip", "--python", python]
    _run([*pip, *"install -q --no-deps --no-index".split(), wheel], where, env)
    return python


def _turn_y_up(src: Path, dst: Path) -> None:
    """The scan of ``src`` turned so that its +y is up (a proper rotation: x stays, the old z
    becomes y, the old y becomes -z), written to ``dst`` as a binary PLY."""
    ply = PlyData.read(str(src))
    vertex = ply["vertex"].data.copy()
    y, z = np.array(vertex["y"]), np.array(vertex["z"])
    vertex["y"], vertex["z"] = z, -y
    element = PlyElement.describe(vertex, "vertex")
    PlyData([element], text=False, comments=ply.comments).write(str(dst))


def _segmented(
    command: Sequence[object], scan: Path, name: str, cwd: Path, env: dict[str, str]
) -> tuple[dict[str, Any], np.ndarray]:
    """The frame section of the report and the points written by ``command segment scan``."""
    out, report = cwd / f"{name}.ply", cwd / f"{name}.json"
    _run([*command, "segment", scan, "-o", out, "--report", report], cwd, env)
    return json.loads(report.read_text())["frame"], PlyData.read(str(out))["vertex"].data


@pytest.mark.slow  # a wheel built and installed: minutes, not for `make test-fast`
def test_the_installed_wheel_segments_a_y_up_room_as_the_checkout_does(
    wheel: Path, tmp_path: Path
) -> None:
    """Everything installed runs from tmp_path, so neither the checkout nor its editable
    install is on sys.path; the checkout's run is this interpreter with the repository on
    PYTHONPATH, on the same file, from the same folder."""
    env = _clean_env()
    python = _fresh_venv(tmp_path / "venv", wheel, env)
    for path in _run([python, "-c", WHERE], tmp_path, env).split():
        assert Path(path).is_relative_to(tmp_path / "venv"), f"not the installed package: {path}"
    installed = [python.parent / "jointseg"]
    room = f"synth --seed {ROOM_SEED} --yaw 0 --points {ROOM_POINTS} -o room.ply".split()
    _run([*installed, *room], tmp_path, env)
    scan = tmp_path / "room_yup.ply"
    _turn_y_up(tmp_path / "room.ply", scan)
    frame, points = _segmented(installed, scan, "installed", tmp_path, env)
    checkout, checkout_env = [sys.executable, "-m", "jointseg"], {**env, "PYTHONPATH": str(ROOT)}
    ref_frame, ref_points = _segmented(checkout, scan, "checkout", tmp_path, checkout_env)
    up, ref_up = frame["up"], ref_frame["up"]
    assert up["axis"] == ref_up["axis"] == "+y"
    assert up["confidence"] == pytest.approx(ref_up["confidence"], abs=1e-6)
    assert up["confidence"] > 0.9
    p, ref_p = up["evidence"]["probabilities"], ref_up["evidence"]["probabilities"]
    assert p == pytest.approx(ref_p, abs=1e-6)
    # runs are deterministic (same seed, same file): the labels are asserted identical
    for field in ("network_label", "fused_label"):
        assert np.array_equal(points[field], ref_points[field]), field
    _check_missing_files_are_named(python, scan, tmp_path, env)


def _check_missing_files_are_named(
    python: Path, scan: Path, cwd: Path, env: dict[str, str]
) -> None:
    """With an installed data file deleted (the fresh environment's copy, never the
    checkout's), segmenting fails naming the up-axis model, and each loader names its file."""
    package = _run([python, "-c", "import jointseg; print(jointseg.__path__[0])"], cwd, env)
    gone = [Path(package.strip()) / f for f in SHIPPED]
    gone[0].unlink()  # the network's weights are read first: only the up-axis model goes here
    segment = [python.parent / "jointseg", "segment", scan, "-o", cwd / "without.ply"]
    done = _call(segment, cwd, env)
    assert done.returncode != 0 and not (cwd / "without.ply").exists()
    assert f"{gone[0]} is missing" in done.stderr, done.stderr
    assert "installation is incomplete" in done.stderr
    for path in gone[1:]:
        path.unlink()
    for code, path in zip(LOADERS, gone, strict=True):
        done = _call([python, "-c", code], cwd, env)
        assert done.returncode != 0 and "ConfigError" in done.stderr, code
        assert str(path) in done.stderr and "installation is incomplete" in done.stderr, code


#: What deptry scans: the packages the wheel ships (bench/, tests/ and scripts/ run in the dev
#: environment), as `make lint` runs it.
DEPTRY = [str(Path(sys.executable).with_name("deptry")), *PACKAGES]
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _deptry(root: Path) -> tuple[int, str]:
    """deptry's exit status and report on the packages under ``root`` (checked against its
    pyproject.toml's dependencies and ``[tool.deptry]``), without colours."""
    done = subprocess.run(DEPTRY, cwd=root, capture_output=True, text=True, timeout=300)
    return done.returncode, ANSI.sub("", done.stdout + done.stderr)


def test_every_module_the_packages_import_is_declared() -> None:
    status, said = _deptry(ROOT)
    assert status == 0 and "No dependency issues found" in said, said[-4000:]


def test_the_dependency_check_fails_on_a_module_imported_but_not_declared(tmp_path: Path) -> None:
    """A copy of the packages and pyproject.toml with shapely's line taken out of the
    dependencies (it still comes with ifcopenshell) and a module no package provides imported:
    deptry names both."""
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=_no_data)
    settings = (ROOT / "pyproject.toml").read_text()
    declared = re.search(r'^ +"shapely[^"]*",\n', settings, re.M)
    assert declared, "pyproject.toml no longer declares shapely: pick another dependency here"
    (tmp_path / "pyproject.toml").write_text(settings.replace(declared.group(0), ""))
    with (tmp_path / "jointseg" / "scan.py").open("a") as fh:
        fh.write("\n\ndef _undeclared() -> None:\n    import no_such_dependency  # noqa: F401\n")
    status, said = _deptry(tmp_path)
    assert status != 0, said[-4000:]
    assert "DEP003 'shapely' imported but it is a transitive dependency" in said, said[-4000:]
    assert "DEP001 'no_such_dependency' imported but missing" in said, said[-4000:]


def _no_data(folder: str, names: list[str]) -> list[str]:
    """What a copy of the packages for deptry leaves out: data files, caches."""
    return [
        n
        for n in names
        if n == "__pycache__" or (Path(folder, n).is_file() and not n.endswith(".py"))
    ]


#: Weights files and fitted models the packages ship with a model card.
CARDS = ("jointseg/network/weights/*.pt", "jointseg/fusion/vote_model.json")


def _shipped_cards() -> dict[str, Any]:
    """The model card of every shipped file that has one, by its path in the project."""
    from jointseg.network.torch_files import read_torch_file

    cards = {}
    for pattern in CARDS:
        for path in sorted(ROOT.glob(pattern)):
            name = str(path.relative_to(ROOT))
            body = read_torch_file(path) if path.suffix == ".pt" else json.loads(path.read_text())
            cards[name] = body["card"]
    return cards


def _strings(value: Any) -> list[str]:
    """Every string in a card, keys included."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for k, v in value.items() for s in (*_strings(k), *_strings(v))]
    if isinstance(value, list | tuple):
        return [s for v in value for s in _strings(v)]
    return []


def test_no_shipped_card_names_a_folder_of_the_machine_it_was_made_on() -> None:
    from jointseg.network.cards import machine_paths

    cards = _shipped_cards()
    assert {
        "jointseg/network/weights/randlanet_indoor.pt",
        "jointseg/fusion/vote_model.json",
    } <= set(cards)
    found = {name: machine_paths(card) for name, card in cards.items() if machine_paths(card)}
    assert not found, f"cards with machine paths (write them with portable_card): {found}"
    climbing = [
        s for c in cards.values() for s in _strings(c) if re.search(r"(^|[/\s=])\.\.[/\\]", s)
    ]
    assert not climbing, climbing
    # the data sets are still named, by their folders' names
    assert "s3dis_area6" in cards["jointseg/network/weights/randlanet_indoor.pt"]["data"]
