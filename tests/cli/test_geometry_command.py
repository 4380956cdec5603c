"""`jointseg geometry` end to end: output fields, report contents, params file errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.io import read_scan, write_scan
from jointseg.metrics import segment_purity
from jointseg.synth import make_room
from tests.support.cli import run_cli


@pytest.fixture(scope="module")
def room_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("geometry") / "room.ply"
    write_scan(make_room(5, points=80_000), path)
    return path


@pytest.mark.slow
def test_geometry_writes_segments_and_report(room_file: Path, tmp_path: Path) -> None:
    out, report = tmp_path / "seg.las", tmp_path / "report.json"
    result = run_cli("geometry", str(room_file), "-o", str(out), "--report", str(report))
    assert result.returncode == 0, result.stderr
    scan = read_scan(out)
    assert {"segment", "main_plane"} <= set(scan.fields)
    body = json.loads(report.read_text())
    assert body["points"] == len(scan) == 80_000
    assert body["segments"] == len(np.unique(scan.fields["segment"]))
    assert body["main_plane_points"] == int(scan.fields["main_plane"].sum())
    assert body["segment_purity"] == pytest.approx(
        segment_purity(scan.labels, scan.fields["segment"])
    )
    assert body["segment_purity"] >= 0.95
    assert {"box_planes", "clustering", "region_growing", "total"} <= set(body["timings_s"])
    # adaptive defaults are reported resolved, not as null
    assert body["params"]["cluster_distance"] > 0 and body["params"]["spacing"] > 0


@pytest.mark.slow
def test_params_file_is_applied(room_file: Path, tmp_path: Path) -> None:
    params, report = tmp_path / "p.json", tmp_path / "r.json"
    params.write_text(json.dumps({"cluster_distance": 0.04, "ransac_iterations": 200}))
    out = tmp_path / "seg.ply"
    result = run_cli(
        "geometry",
        str(room_file),
        "-o",
        str(out),
        "--params",
        str(params),
        "--report",
        str(report),
    )
    assert result.returncode == 0, result.stderr
    body = json.loads(report.read_text())
    assert body["params"]["cluster_distance"] == 0.04
    assert body["params"]["ransac_iterations"] == 200


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"cluster_distanse": 0.04}', "cluster_distanse"),
        ('{"ransac_iterations": -5}', "ransac_iterations"),
        ("{not json", "not valid JSON"),
    ],
)
def test_bad_params_file_exits_2_and_writes_nothing(
    room_file: Path, tmp_path: Path, content: str, message: str
) -> None:
    params = tmp_path / "p.json"
    params.write_text(content)
    out = tmp_path / "seg.ply"
    result = run_cli("geometry", str(room_file), "-o", str(out), "--params", str(params))
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert not out.exists()


@pytest.mark.slow
def test_geometry_levels_a_y_up_millimetre_scan_first(tmp_path: Path) -> None:
    from jointseg.scan import Scan

    room = make_room(4, points=30_000)
    yup = tmp_path / "yup_mm.ply"
    write_scan(
        Scan(room.xyz[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0]) * 1000.0, room.rgb, room.labels),
        yup,
    )
    level = tmp_path / "level.ply"
    write_scan(room, level)
    purities = []
    for source in (level, yup):
        out, report = tmp_path / f"{source.stem}_seg.ply", tmp_path / f"{source.stem}.json"
        result = run_cli("geometry", str(source), "-o", str(out), "--report", str(report))
        assert result.returncode == 0, result.stderr
        body = json.loads(report.read_text())
        purities.append(body["segment_purity"])
    assert body["frame"]["up"]["axis"] == "+y" and body["frame"]["units"]["unit"] == "mm"
    assert purities[1] >= purities[0] - 0.02, purities  # as pure as the level scan's segments
    assert np.array_equal(read_scan(out).xyz, read_scan(yup).xyz)
