"""Training data sources: a folder of labelled scans with a held-out validation split, mixed with
synthetic rooms; class-balanced crop centres; a few real training steps on such a folder."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.exceptions import ConfigError
from jointseg.io import write_scan
from jointseg.network.randlanet.checkpoint import load_checkpoint
from jointseg.synth import make_room
from jointseg.training.data import (
    centre_weights,
    labelled_scan_files,
    split_validation,
    stable_order,
)
from jointseg.training.loop import train


@pytest.fixture(scope="module")
def scan_folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("rooms")
    for seed in range(3):
        write_scan(make_room(400 + seed, points=15_000), root / f"room_{seed}.ply")
    (root / "notes.md").write_text("not a scan")
    return root


def test_the_validation_split_is_stable_and_named_scans_win() -> None:
    names = [f"room_{i}" for i in range(10)]
    first = split_validation(names, [], 3)
    assert first == split_validation(list(reversed(names)), [], 3) == stable_order(names)[:3]
    assert split_validation(names, ["room_7"], 3) == ["room_7"]
    with pytest.raises(ConfigError, match="room_99"):
        split_validation(names, ["room_99"], 3)
    with pytest.raises(ConfigError, match="val_count=10"):
        split_validation(names, [], 10)


def test_a_folder_without_scans_is_refused(tmp_path) -> None:
    (tmp_path / "a.txt.bak").write_text("x")
    with pytest.raises(ConfigError, match="no scan files"):
        labelled_scan_files(tmp_path)
    with pytest.raises(ConfigError, match="not a folder"):
        labelled_scan_files(tmp_path / "missing")


def test_centre_weights_favour_rare_classes() -> None:
    labels = np.array([0] * 90 + [11] * 10 + [-1] * 5)
    class_weight = np.ones(13)
    class_weight[11] = 9.0
    p = centre_weights(labels, class_weight)
    assert np.isclose(p.sum(), 1)
    # ten board points drawn as often as the ninety ceiling points together
    assert np.isclose(p[labels == 11].sum(), p[labels == 0].sum())


@pytest.mark.slow
def test_training_on_a_folder_keeps_the_validation_scans_out(scan_folder, tiny_training) -> None:
    cfg = tiny_training(data=str(scan_folder), val_scans=["room_1"], synth_share=0.5)
    _, card, _ = load_checkpoint(train(cfg))
    data = card["data"]
    assert "2 labelled scans" in data and "validation (never trained on): room_1" in data
    trained = data.split("labelled scans from")[1].split("(")[1].split(")")[0]
    assert "room_1" not in trained and "room_0" in trained
    assert card["sources"] == {scan_folder.name: 0.5, "synth": 0.5}
    assert "jointseg.synth" in data and "50% of crops" in data
    assert 0.0 <= card["history"][0]["val_miou"] <= 1.0


def test_a_scan_without_labels_is_refused(tmp_path, tiny_training) -> None:
    room = make_room(5, points=15_000)
    for i in range(2):
        write_scan(room.with_fields(), tmp_path / f"r{i}.ply")
    unlabelled = make_room(6, points=15_000)
    write_scan(type(unlabelled)(xyz=unlabelled.xyz, rgb=unlabelled.rgb), tmp_path / "bare.ply")
    with pytest.raises(ConfigError, match="bare.ply: no 'label' field"):
        train(tiny_training(data=str(tmp_path), val_count=1))
