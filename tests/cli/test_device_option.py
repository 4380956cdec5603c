"""`--device` of `jointseg segment` and `jointseg eval` (issue 25): it overrides the config's
network device, the report says where the network ran, and a device this machine cannot give is
refused before any work, with nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from jointseg.exceptions import ConfigError
from jointseg.io import write_scan
from jointseg.network.base import pick_device
from jointseg.pipeline.config import PipelineConfig
from jointseg.synth import make_room
from tests.support.cli import run_cli

no_cuda = pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("device_room") / "room.ply"
    write_scan(make_room(23, points=8_000), path)
    return path


@pytest.mark.slow
def test_segment_device_cpu_overrides_the_config(room: Path, random_weights, tmp_path) -> None:
    config = tmp_path / "cfg.json"
    config.write_text(json.dumps({"network": {"device": "cuda"}}))  # the option wins
    out, report = tmp_path / "out.ply", tmp_path / "report.json"
    result = run_cli(
        "segment", str(room), "-o", str(out), "--report", str(report),
        "--weights", str(random_weights), "--config", str(config), "--device", "cpu",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert json.loads(report.read_text())["params"]["network"]["device"] == "cpu"


@pytest.mark.slow
@no_cuda
@pytest.mark.parametrize("command", ["segment", "eval"])
def test_device_cuda_without_cuda_fails_at_once(room: Path, tmp_path, command) -> None:
    if command == "segment":
        args = [str(room), "-o", "out.ply", "--report", "r.json"]
    else:
        args = [str(room), "--out", "tables"]
    result = run_cli(command, *args, "--device", "cuda", cwd=tmp_path)
    assert result.returncode == 2
    assert "sees no CUDA device" in result.stderr and "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
@no_cuda
def test_config_file_asking_for_cuda_fails_at_once(room: Path, tmp_path) -> None:
    (tmp_path / "cfg.json").write_text(json.dumps({"network": {"device": "cuda"}}))
    result = run_cli(
        "segment", str(room), "-o", "out.ply", "--config", "cfg.json", cwd=tmp_path
    )  # fmt: skip
    assert result.returncode == 2
    assert "sees no CUDA device" in result.stderr and "Traceback" not in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cfg.json"]


@pytest.mark.slow
@pytest.mark.parametrize("device", ["tpu", "gpu", "cuda:x", "CPU"])
def test_unknown_device_is_refused(room: Path, tmp_path, device) -> None:
    result = run_cli("segment", str(room), "-o", "out.ply", "--device", device, cwd=tmp_path)
    assert result.returncode == 2
    assert f"device {device!r}: unknown device" in result.stderr
    assert "Traceback" not in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_unknown_device_in_a_config_is_a_validation_error() -> None:
    with pytest.raises(ValueError, match="network.device"):
        PipelineConfig.model_validate({"network": {"device": "tpu"}})
    assert PipelineConfig.model_validate({"network": {"device": "cuda:1"}}).network.device


def test_with_network_device_overrides_and_checks() -> None:
    cfg = PipelineConfig.model_validate({"network": {"device": "cuda", "batch_size": 4}})
    cpu = cfg.with_network(device="cpu")
    assert cpu.network.device == "cpu" and cpu.network.batch_size == 4
    assert cfg.with_network().network.device == "cuda"
    with pytest.raises(ConfigError, match="unknown device"):
        cfg.with_network(device="tpu")


def test_pick_device() -> None:
    assert pick_device("cpu") == torch.device("cpu")
    assert pick_device(None).type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ConfigError, match="unknown device"):
        pick_device("mps")
    with pytest.raises(ConfigError):
        pick_device(f"cuda:{torch.cuda.device_count()}")  # one past the last (or no CUDA)
