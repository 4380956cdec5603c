"""The learned vote: its tree evaluator, the shipped model and its card, and what it decides on
hand-made segments (an unsure point in a confident segment follows it; a confident minority that
is an object of its own keeps the network's label)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.exceptions import ConfigError
from jointseg.fusion import FusionParams, fuse
from jointseg.fusion.learned import (
    FEATURES,
    MODEL_PATH,
    TreeEnsemble,
    shipped_model,
    vote_features,
)
from jointseg.network.train_data import stable_order
from tests.fusion.test_evidence import probs_for

LEARNED = FusionParams(mode="learned")


def stump_model(path: Path, *, feature: int, threshold: float) -> Path:
    """One tree: x[feature] <= threshold gives -2, else +3; base 0.5."""
    tree = {
        "feature": [feature, 0, 0],
        "threshold": [threshold, 0.0, 0.0],
        "left": [1, 0, 0],
        "right": [2, 0, 0],
        "value": [0.0, -2.0, 3.0],
        "leaf": [False, True, True],
    }
    path.write_text(json.dumps({"features": list(FEATURES), "base": 0.5, "trees": [tree]}))
    return path


def test_tree_evaluator_follows_the_splits(tmp_path) -> None:
    model = TreeEnsemble.from_json(stump_model(tmp_path / "m.json", feature=2, threshold=0.0))
    x = np.zeros((3, len(FEATURES)))
    x[:, 2] = [-1.0, 0.0, 1.0]
    expected = 1 / (1 + np.exp(-np.array([0.5 - 2, 0.5 - 2, 0.5 + 3])))
    np.testing.assert_allclose(model.probability(x), expected)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("{not json", "vote model"),
        (json.dumps({"features": ["a"], "base": 0, "trees": []}), "features"),
        (json.dumps({"features": list(FEATURES), "trees": []}), "base"),
    ],
)
def test_a_broken_model_file_is_a_config_error(tmp_path, body, message) -> None:
    path = tmp_path / "bad.json"
    path.write_text(body)
    with pytest.raises(ConfigError, match=message):
        TreeEnsemble.from_json(path)


def test_features_are_computed_only_where_the_segment_disagrees() -> None:
    probs = probs_for([{2: 0.9}] * 8 + [{5: 0.6, 2: 0.3}] * 2)
    labels = probs.argmax(axis=1)
    seg = np.zeros(10, dtype=np.int64)
    candidate, open_, x = vote_features(seg, 1, labels, probs)
    assert (candidate == 2).all()
    assert open_.tolist() == [8, 9]
    assert x.shape == (2, len(FEATURES))
    # p(own) > p(segment label) at the open points; hard share of the segment label 0.8
    assert (x[:, 0] > x[:, 1]).all()
    np.testing.assert_allclose(x[:, 4], np.log(0.8 / 0.2))


def wall_with(extra: list[dict[int, float]], walls: int = 200) -> tuple[np.ndarray, ...]:
    probs = probs_for([{2: 0.9, 5: 0.05}] * walls + extra)
    xyz = np.column_stack(
        [np.arange(len(probs)) * 0.01, np.zeros(len(probs)), np.zeros(len(probs))]
    )
    return xyz, probs, probs.argmax(axis=1)


def test_an_unsure_point_follows_a_confident_segment() -> None:
    xyz, probs, labels = wall_with([{5: 0.45, 2: 0.4}] * 3)
    result = fuse(xyz, np.zeros(len(xyz), int), labels, probs, LEARNED)
    assert (labels[-3:] == 5).all()
    assert (result.labels == 2).all()


def test_a_confident_object_inside_a_plane_keeps_its_label() -> None:
    # a board the network is sure of (0.97), a fifth of its wall segment
    xyz, probs, labels = wall_with([{11: 0.97, 2: 0.02}] * 50)
    result = fuse(xyz, np.zeros(len(xyz), int), labels, probs, LEARNED)
    assert (result.labels[-50:] == 11).all()
    assert (result.labels[:-50] == 2).all()


def test_the_shipped_model_never_saw_a_judging_room(shared_file) -> None:
    card = shipped_model().card
    assert card["trained_on"]["real"], card
    rooms = sorted(p.stem for p in shared_file("data/s3dis_area6").glob("*.ply"))
    judging = set(stable_order(rooms)[:10])  # bench/fusion_real.py --judge 10
    assert not judging & set(card["trained_on"]["real"])
    assert MODEL_PATH.stat().st_size < 100_000
