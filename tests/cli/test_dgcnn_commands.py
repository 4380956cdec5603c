"""`--network dgcnn` in predict and segment, and `models list`, through the real entry point
(random DGCNN weights in dgcnn.pytorch's file layout)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.io import read_scan, write_scan
from jointseg.scan import Scan
from jointseg.synth import make_room
from tests.support.cli import run_cli

#: each test runs the CLI with DGCNN in a subprocess: not for `make test-fast`
pytestmark = pytest.mark.slow

ENV = "JOINTSEG_DGCNN_WEIGHTS"


@pytest.fixture(scope="module")
def one_column(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A labelled scan inside one 1 m column: a single 4 096-point block."""
    rng = np.random.default_rng(0)
    xyz = rng.uniform(0, 0.9, (3000, 3))
    rgb = rng.integers(0, 256, (3000, 3)).astype(np.uint8)
    labels = (xyz[:, 2] > 0.1).astype(np.int32) + 1
    path = tmp_path_factory.mktemp("dgcnn_cli") / "column.ply"
    write_scan(Scan(xyz, rgb, labels), path)
    return path


def test_models_list_shows_dgcnn_and_where_to_get_it(dgcnn_random_weights) -> None:
    result = run_cli("models", "list", unset=[ENV])
    assert result.returncode == 0, result.stderr
    assert "dgcnn" in result.stdout and "antao97" in result.stdout
    result = run_cli("models", "list", env={ENV: str(dgcnn_random_weights), "COLUMNS": "200"})
    assert result.returncode == 0, result.stderr
    assert "Area 9 held out" in result.stdout and ENV in result.stdout


def test_predict_with_dgcnn(one_column: Path, dgcnn_random_weights, tmp_path) -> None:
    out = tmp_path / "pred.ply"
    result = run_cli(
        "predict", str(one_column), "-o", str(out), "--network", "dgcnn",
        "--weights", str(dgcnn_random_weights), unset=[ENV],
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "with dgcnn" in result.stderr and "(1 crops)" in result.stderr
    back = read_scan(out)
    assert back.fields["network_label"].shape == (3000,)
    assert (back.fields["network_confidence"] > 0).all()


def test_dgcnn_without_weights_says_where_to_get_them(one_column: Path, tmp_path) -> None:
    out = tmp_path / "pred.ply"
    result = run_cli("predict", str(one_column), "-o", str(out), "--network", "dgcnn", unset=[ENV])
    assert result.returncode == 2
    assert "jointseg models pull dgcnn-s3dis-5" in result.stderr and ENV in result.stderr
    assert "Traceback" not in result.stderr and not out.exists()


def test_segment_with_dgcnn_from_the_environment_and_its_config(
    dgcnn_random_weights, tmp_path
) -> None:
    scan = tmp_path / "room.ply"
    write_scan(make_room(21, points=8_000), scan)
    config = tmp_path / "cfg.json"
    config.write_text(json.dumps({"network": {"dgcnn": {"num_points": 256, "frame": "scan"}}}))
    out, report = tmp_path / "out.ply", tmp_path / "report.json"
    result = run_cli(
        "segment", str(scan), "-o", str(out), "--report", str(report), "--network", "dgcnn",
        "--config", str(config), env={ENV: str(dgcnn_random_weights)},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    network = json.loads(report.read_text())["params"]["network"]
    assert network["name"] == "dgcnn" and network["weights"] == str(dgcnn_random_weights)
    assert network["dgcnn"]["num_points"] == 256 and network["dgcnn"]["frame"] == "scan"
    assert network["trained_on"] == "S3DIS, Area 9 held out"


def test_misspelt_dgcnn_option_is_named(one_column: Path, tmp_path) -> None:
    config = tmp_path / "cfg.json"
    config.write_text(json.dumps({"network": {"dgcnn": {"strid": 1.0}}}))
    result = run_cli(
        "segment", str(one_column), "-o", str(tmp_path / "o.ply"), "--config", str(config),
        unset=[ENV],
    )  # fmt: skip
    assert result.returncode == 2 and "strid" in result.stderr
