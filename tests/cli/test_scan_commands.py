"""`jointseg synth`, `info` and `convert` run as a user runs them: the real console entry point
in a subprocess, checking files written, what is printed and exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.io import read_scan, write_scan
from jointseg.synth import make_room
from tests.support.cli import run_cli


@pytest.fixture(scope="module")
def room_ply(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cli") / "room.ply"
    result = run_cli("synth", "--seed", "3", "--points", "60000", "--yaw", "0", "-o", str(out))
    assert result.returncode == 0, result.stderr
    return out


@pytest.mark.slow
def test_synth_writes_the_requested_room(room_ply: Path) -> None:
    scan = read_scan(room_ply)
    assert len(scan) == 60_000
    assert scan.rgb is not None and scan.labels is not None
    assert set(np.unique(scan.labels)) <= set(range(13))
    assert "instance" in scan.fields


@pytest.mark.slow
def test_synth_is_deterministic(tmp_path: Path, room_ply: Path) -> None:
    again = tmp_path / "again.ply"
    args = ("synth", "--seed", "3", "--points", "60000", "--yaw", "0", "-o", str(again))
    assert run_cli(*args).returncode == 0
    a, b = read_scan(room_ply), read_scan(again)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.labels, b.labels)


@pytest.mark.slow
def test_info_json_describes_the_scan(room_ply: Path) -> None:
    result = run_cli("info", "--json", str(room_ply))
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    scan = read_scan(room_ply)
    assert summary["points"] == len(scan)
    assert summary["label_histogram"]["wall"] == int(np.sum(scan.labels == 2))
    assert sum(summary["label_histogram"].values()) == len(scan)
    assert summary["bounds_min"] == pytest.approx(scan.xyz.min(axis=0).tolist())
    assert 0.001 < summary["spacing"] < 0.2
    assert {"instance"} <= {f["name"] for f in summary["fields"]}


@pytest.mark.slow
def test_info_text_lists_classes_and_spacing(room_ply: Path) -> None:
    result = run_cli("info", str(room_ply))
    assert result.returncode == 0, result.stderr
    assert "60,000" in result.stdout
    assert "spacing" in result.stdout and "mm" in result.stdout
    assert "ceiling" in result.stdout and "wall" in result.stdout


@pytest.mark.parametrize("ext", ["las", "laz", "pcd", "txt", "npz"])
def test_convert_keeps_points_colour_and_labels(room_ply: Path, tmp_path: Path, ext: str) -> None:
    out = tmp_path / f"room.{ext}"
    result = run_cli("convert", str(room_ply), str(out))
    assert result.returncode == 0, result.stderr
    a, b = read_scan(room_ply), read_scan(out)
    assert len(b) == len(a)
    np.testing.assert_allclose(b.xyz, a.xyz, atol=1e-3)
    np.testing.assert_array_equal(b.rgb, a.rgb)
    np.testing.assert_array_equal(b.labels, a.labels)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("info", "missing.ply"), "missing.ply"),
        (("info", "{bad}"), "PLY"),
        (("convert", "{room}", "{tmp}/out.xyzzy"), "xyzzy"),
        (("info", "--max-points", "100", "{room}"), "100"),
        (("synth", "--points", "10", "-o", "{tmp}/x.ply"), "points"),
    ],
)
def test_bad_input_exits_2_with_one_clear_line(
    args: tuple[str, ...], message: str, room_ply: Path, tmp_path: Path
) -> None:
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"this is not a point cloud\n")
    filled = [a.format(bad=bad, room=room_ply, tmp=tmp_path) for a in args]
    result = run_cli(*filled)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "error" in result.stderr.lower()
    assert message in result.stderr
    assert not (tmp_path / "out.xyzzy").exists()
    assert not (tmp_path / "x.ply").exists()


@pytest.mark.slow
def test_info_tells_the_up_axis_and_units_it_finds(tmp_path: Path) -> None:
    from jointseg.scan import Scan

    room = make_room(8, points=20_000)
    path = tmp_path / "yup_mm.ply"
    write_scan(Scan(room.xyz[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0]) * 1000.0, room.rgb), path)
    body = json.loads(run_cli("info", str(path), "--json").stdout)
    assert body["frame"]["up"]["axis"] == "+y" and body["frame"]["units"]["unit"] == "mm"
    text = run_cli("info", str(path)).stdout
    assert "units mm" in text and "up +y" in text
