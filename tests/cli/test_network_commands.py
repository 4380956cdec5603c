"""`jointseg predict` and `jointseg models` through the real console entry point."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from jointseg.io import read_scan, write_scan
from jointseg.network.randlanet.checkpoint import save_checkpoint
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig
from jointseg.synth import make_room
from tests.support.cli import run_cli


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("predict")
    torch.manual_seed(0)
    weights = root / "random.pt"
    save_checkpoint(weights, RandLANet(RandLANetConfig(num_points=4096)), {"data": "random"})
    scan = root / "room.ply"
    write_scan(make_room(2, points=20_000), scan)
    return scan, weights


@pytest.mark.slow
def test_predict_writes_network_fields(files: tuple[Path, Path], tmp_path: Path) -> None:
    scan, weights = files
    out = tmp_path / "pred.laz"
    result = run_cli("predict", str(scan), "-o", str(out), "--weights", str(weights))
    assert result.returncode == 0, result.stderr
    back = read_scan(out)
    assert len(back) == 20_000
    labels, conf = back.fields["network_label"], back.fields["network_confidence"]
    assert labels.min() >= 0 and labels.max() <= 12
    assert (conf > 0).all() and (conf <= 1).all()
    np.testing.assert_array_equal(back.labels, read_scan(scan).labels)  # ground truth kept


def test_predict_without_weights_says_where_to_get_them(files, tmp_path: Path) -> None:
    scan, _ = files
    result = run_cli(
        "predict", str(scan), "-o", str(tmp_path / "x.ply"), "--weights", str(tmp_path / "none.pt")
    )
    assert result.returncode == 2
    assert "jointseg train" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "x.ply").exists()


@pytest.mark.slow
def test_models_list_shows_randlanet() -> None:
    result = run_cli("models", "list")
    assert result.returncode == 0, result.stderr
    assert "randlanet" in result.stdout
    assert "randlanet card: " in result.stdout and " epochs" in result.stdout


@pytest.mark.slow
def test_models_pack_strips_optimiser_and_halves_the_size(tmp_path: Path, tiny_training) -> None:
    from jointseg.network.randlanet.checkpoint import load_checkpoint
    from jointseg.training.loop import train

    source = train(tiny_training(out=tmp_path / "train.pt", steps_per_epoch=1))
    packed = tmp_path / "ship.pt"
    result = run_cli("models", "pack", str(source), "-o", str(packed))
    assert result.returncode == 0, result.stderr
    assert packed.stat().st_size < 0.4 * source.stat().st_size  # no Adam moments, float16
    full, card_full, _ = load_checkpoint(source)
    half, card, body = load_checkpoint(packed)
    assert "optimizer" not in body and card["weights_dtype"] == "float16"
    assert card["history"] == card_full["history"] and card["input_conventions"]
    for (name, a), b in zip(full.state_dict().items(), half.state_dict().values(), strict=True):
        if a.is_floating_point():
            assert torch.allclose(a, b, rtol=2e-3, atol=1e-4), name


@pytest.mark.slow
def test_models_pack_refuses_a_foreign_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    result = run_cli("models", "pack", str(bad), "-o", str(tmp_path / "out.pt"))
    assert result.returncode == 2 and "not a readable PyTorch checkpoint" in result.stderr
    assert not (tmp_path / "out.pt").exists()


@pytest.mark.slow
def test_train_with_bad_sources_is_a_one_line_error(tmp_path: Path) -> None:
    result = run_cli(
        "train", "--data", f"{tmp_path}:0.7", "--data", "synth:0.7", "--out", str(tmp_path / "m.pt")
    )
    assert result.returncode == 2
    assert "add up to 1.4" in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "m.pt").exists()


@pytest.mark.slow
def test_predict_levels_a_y_up_millimetre_scan_like_segment(tmp_path: Path) -> None:
    from jointseg.scan import Scan

    room = make_room(2, points=20_000)
    level, yup = tmp_path / "level.ply", tmp_path / "yup_mm.ply"
    write_scan(room, level)
    write_scan(Scan(room.xyz[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0]) * 1000.0, room.rgb), yup)
    outs = []
    for name, source in (("level", level), ("yup", yup)):
        out = tmp_path / f"{name}_pred.ply"
        result = run_cli(
            "predict", str(source), "-o", str(out), "--up", "+y" if name == "yup" else "auto"
        )
        assert result.returncode == 0, result.stderr
        outs.append(read_scan(out))
    assert "frame: up +y (set by the user" in result.stderr and "units mm" in result.stderr
    agree = np.mean(outs[0].fields["network_label"] == outs[1].fields["network_label"])
    assert agree >= 0.9, agree
    assert np.array_equal(outs[1].xyz, read_scan(yup).xyz)
    bad = run_cli("predict", str(yup), "-o", str(tmp_path / "x.ply"), "--units", "furlong")
    assert bad.returncode == 2 and "--units" in bad.stderr and "Traceback" not in bad.stderr
