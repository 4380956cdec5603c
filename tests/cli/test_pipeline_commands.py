"""`jointseg segment` and `jointseg eval` through the real entry point, with a random network."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

from jointseg.classes import CLASS_NAMES
from jointseg.io import read_scan, write_scan
from jointseg.metrics import evaluate
from jointseg.pipeline import OUTPUT_FIELDS
from jointseg.scan import Scan
from jointseg.synth import make_room
from tests.support.cli import run_cli

#: each test runs the CLI with the network in a subprocess: not for `make test-fast`
pytestmark = pytest.mark.slow

FIELDS = set(OUTPUT_FIELDS)


@pytest.fixture(scope="module")
def rooms(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("rooms")
    write_scan(make_room(21, points=20_000), folder / "room_1.ply")
    write_scan(make_room(22, points=20_000, shape="L"), folder / "room_2.ply")
    return folder


def test_segment_writes_every_field_and_a_report(rooms: Path, random_weights, tmp_path) -> None:
    out, report = tmp_path / "out.ply", tmp_path / "report.json"
    source = rooms / "room_1.ply"
    result = run_cli(
        "segment", str(source), "-o", str(out), "--report", str(report),
        "--weights", str(random_weights),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "mIoU network" in result.stderr
    scan = read_scan(out)
    original = read_scan(source)
    assert FIELDS <= set(scan.fields) and scan.rgb is not None
    np.testing.assert_array_equal(scan.labels, original.labels)  # ground truth kept as label
    body = json.loads(report.read_text())
    assert body["points"] == len(scan) == 20_000
    assert body["segments"] == len(np.unique(scan.fields["segment"]))
    timings = body["timings_s"]
    assert {"read", "network", "geometry", "fusion", "write", "total"} <= set(timings)
    assert timings["total"] >= timings["network"]
    assert body["params"]["geometry"]["spacing"] > 0  # resolved, not null
    assert body["params"]["fusion"]["mode"] and body["params"]["network"]["weights"]
    fused = evaluate(scan.labels, scan.fields["fused_label"])
    assert body["metrics"]["fused"]["miou"] == pytest.approx(fused.miou)
    assert set(body["metrics"]) == {"network", "fused", "oracle"}
    for metrics in body["metrics"].values():
        assert set(metrics["per_class_iou"]) == set(CLASS_NAMES)
        assert {"miou", "macc", "oa"} <= set(metrics)
    absent = [c for c, v in fused.per_class_iou.items() if v is None]
    assert all(body["metrics"]["fused"]["per_class_iou"][c] is None for c in absent)


def test_segment_to_laz_of_an_unlabelled_scan(rooms: Path, random_weights, tmp_path) -> None:
    room = read_scan(rooms / "room_1.ply")
    source = tmp_path / "plain.ply"
    write_scan(Scan(room.xyz, room.rgb), source)
    out, report = tmp_path / "out.laz", tmp_path / "r.json"
    result = run_cli(
        "segment", str(source), "-o", str(out), "--report", str(report),
        "--weights", str(random_weights),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    scan = read_scan(out)
    assert FIELDS <= set(scan.fields)
    assert json.loads(report.read_text())["metrics"] is None
    # LAS tools find the result in classification (64 + class, strays 1); jointseg does not
    # take it for ground truth
    import laspy

    las = laspy.read(out)
    fused, stray = scan.fields["fused_label"], scan.fields["stray"]
    np.testing.assert_array_equal(las.classification, np.where(stray == 1, 1, 64 + fused))
    assert "input_classification" not in las.point_format.extra_dimension_names
    assert scan.labels is None


def test_config_file_is_applied(rooms: Path, random_weights, tmp_path) -> None:
    config, report = tmp_path / "cfg.json", tmp_path / "r.json"
    config.write_text(
        json.dumps(
            {
                "network": {"weights": str(random_weights), "batch_size": 2},
                "geometry": {"cluster_distance": 0.05},
                "fusion": {"mode": "paper", "ratio_threshold": 0.3},
                "seed": 4,
            }
        )
    )
    out = tmp_path / "out.ply"
    result = run_cli(
        "segment", str(rooms / "room_1.ply"), "-o", str(out), "--config", str(config),
        "--report", str(report),
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    params = json.loads(report.read_text())["params"]
    assert params["geometry"]["cluster_distance"] == 0.05
    assert params["fusion"]["mode"] == "paper" and params["fusion"]["ratio_threshold"] == 0.3
    assert params["network"]["batch_size"] == 2 and params["seed"] == 4


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"fusion": {"ratio_treshold": 0.3}}', "fusion.ratio_treshold"),
        ('{"netwrok": {}}', "netwrok"),
        ('{"fusion": {"mode": "vote"}}', "fusion.mode"),
        ("{not json", "not valid JSON"),
    ],
)
def test_bad_config_exits_2_and_writes_nothing(rooms: Path, tmp_path, content, message) -> None:
    config = tmp_path / "cfg.json"
    config.write_text(content)
    out, report = tmp_path / "out.ply", tmp_path / "r.json"
    result = run_cli(
        "segment", str(rooms / "room_1.ply"), "-o", str(out), "--config", str(config),
        "--report", str(report),
    )  # fmt: skip
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert not out.exists() and not report.exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--weights", "missing.pt"], "jointseg train"),
        (["--network", "pointnet"], "unknown network 'pointnet'"),
        (["-o", "out.txt"], "cannot store the output fields"),
        (["--up", "sideways"], "frame.up"),
        (["--units", "furlong"], "frame.units"),
        (["--colour-free", "maybe"], "network.colour_free"),
    ],
)
def test_bad_options_exit_2_and_write_nothing(rooms: Path, tmp_path, extra, message) -> None:
    args = ["segment", str(rooms / "room_1.ply"), "-o", "out.ply", "--report", "r.json", *extra]
    result = run_cli(*args, cwd=tmp_path)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_eval_prints_the_paper_tables_and_writes_csv_and_json(
    rooms: Path, random_weights, tmp_path
) -> None:
    out = tmp_path / "eval"
    result = run_cli("eval", str(rooms), "--weights", str(random_weights), "--out", str(out))
    assert result.returncode == 0, result.stderr
    text = result.stdout
    assert "Table 1" in text and "Table 2" in text and "ceil." in text and "clut." in text
    assert "room_1" in text and "room_2" in text and "network" in text and "fused" in text
    with open(out / "table1.csv") as fh:
        table1 = list(csv.reader(fh))
    assert table1[0][:3] == ["room", "method", "ceil."] and len(table1[0]) == 15
    assert [row[:2] for row in table1[1:5]] == [
        ["room_1", "network"], ["room_1", "fused"], ["room_2", "network"], ["room_2", "fused"],
    ]  # fmt: skip
    with open(out / "table2.csv") as fh:
        table2 = list(csv.reader(fh))
    assert table2[0] == ["room", "method", "mIoU", "mAcc"]
    body = json.loads((out / "eval.json").read_text())
    absent = any(v is None for row in body["table1"]["rows"] for v in row)
    assert absent == bool(re.search(r" /( |$)", text, re.M))  # absent classes print as '/'
    assert [room["name"] for room in body["rooms"]] == ["room_1", "room_2"]
    fused = body["rooms"][0]["metrics"]["fused"]
    assert float(table2[2][2]) == pytest.approx(fused["miou"])
    assert body["table2"]["rows"][1][2] == pytest.approx(fused["miou"])


def test_eval_refuses_unlabelled_scans_before_any_work(
    rooms: Path, random_weights, tmp_path
) -> None:
    room = read_scan(rooms / "room_1.ply")
    plain = tmp_path / "plain.ply"
    write_scan(Scan(room.xyz, room.rgb), plain)
    out = tmp_path / "eval"
    result = run_cli(
        "eval", str(rooms / "room_2.ply"), str(plain), "--weights", str(random_weights),
        "--out", str(out),
    )  # fmt: skip
    assert result.returncode == 2
    assert "plain.ply" in result.stderr and "no ground-truth labels" in result.stderr
    assert "Traceback" not in result.stderr and not out.exists()


def test_segment_prints_the_frame_and_takes_up_and_units(random_weights, tmp_path) -> None:
    room = make_room(23, points=20_000)
    source = tmp_path / "yup_mm.ply"
    write_scan(Scan(room.xyz[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0]) * 1000.0, room.rgb), source)
    out, report = tmp_path / "out.ply", tmp_path / "report.json"
    result = run_cli(
        "segment", str(source), "-o", str(out), "--report", str(report),
        "--weights", str(random_weights), "--up", "+y", "--units", "mm",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "frame: up +y (set by the user" in result.stderr and "units mm" in result.stderr
    frame = json.loads(report.read_text())["frame"]
    assert frame["up"]["axis"] == "+y" and frame["units"]["metres_per_unit"] == 0.001
    assert np.array_equal(read_scan(out).xyz, read_scan(source).xyz)
