"""Classes a scan does not hold: scattered labels taken out, real classes kept."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.exceptions import ConfigError
from jointseg.network.presence import absent_classes, drop_absent
from jointseg.network.randlanet.params import RandLANetParams


def _probs(winners: np.ndarray, runner_up: int = 2) -> np.ndarray:
    """Cells won by ``winners``; class ``runner_up`` second, then class 0 third."""
    probs = np.full((len(winners), 13), 0.01, dtype=np.float32)
    probs[np.arange(len(winners)), winners] = 0.7
    probs[np.arange(len(winners)), runner_up] += 0.15
    probs[:, 0] += 0.05
    return probs / probs.sum(axis=1, keepdims=True)


def test_a_scattered_class_is_taken_out_and_its_cells_take_the_next_class() -> None:
    winners = np.r_[np.zeros(6000, int), np.ones(3900, int), np.full(30, 3), np.full(70, 11)]
    probs = _probs(winners)
    absent = absent_classes(probs, 0.005, 2000)
    # 30 < 50 cells; 70 >= 50 stays; classes that win nowhere are absent too
    assert absent.tolist() == [i not in (0, 1, 11) for i in range(13)]
    kept = drop_absent(probs, 0.005, 2000)
    labels = kept.argmax(axis=1)
    assert (labels[winners == 3] == 0).all()  # the runner-up among the classes present
    assert (labels[winners != 3] == winners[winners != 3]).all()
    assert np.allclose(kept.sum(axis=1), 1) and (kept[:, 3] == 0).all()


def test_a_small_real_class_on_a_big_floor_stays() -> None:
    """Beyond absent_max_cells a class is never absent, whatever its share."""
    winners = np.r_[np.zeros(2_000_000, int), np.full(3000, 11)]
    probs = _probs(winners)
    assert not absent_classes(probs, 0.005, 2000)[[0, 11]].any()
    assert drop_absent(probs, 0.005, 2000) is probs
    assert absent_classes(probs, 0.005, 5000)[11]


def test_off_when_the_share_is_zero_and_options_are_checked() -> None:
    probs = _probs(np.r_[np.zeros(1000, int), np.full(2, 5)])
    assert drop_absent(probs, 0.0, 2000) is probs
    with pytest.raises(ValueError, match="absent_share"):
        RandLANetParams(absent_share=0.7)


def test_the_option_reaches_the_predictor_through_the_pipeline_config(random_weights) -> None:
    from jointseg.pipeline.config import PipelineConfig

    cfg = PipelineConfig.model_validate(
        {"network": {"weights": str(random_weights), "randlanet": {"absent_share": 0.01}}}
    )
    assert cfg.network.options() == RandLANetParams(absent_share=0.01)
    with pytest.raises((ValueError, ConfigError)):
        PipelineConfig.model_validate({"network": {"randlanet": {"absent": 1}}})


@pytest.mark.slow
def test_whole_scan_inference_applies_it(small_room) -> None:
    from jointseg.network import load
    from jointseg.network.registry import REGISTRY

    weights = REGISTRY["randlanet"].bundled
    raw = load("randlanet", weights, params=RandLANetParams(absent_share=0)).predict(small_room)
    pruned = load("randlanet", weights, params=RandLANetParams(absent_share=0.05)).predict(
        small_room
    )
    raw_share = np.bincount(raw.labels, minlength=13) / len(raw.labels)
    assert (raw_share[raw_share > 0] < 0.05).any()  # some classes are on few points
    share = np.bincount(pruned.labels, minlength=13) / len(pruned.labels)
    assert set(np.flatnonzero(share)) < set(np.flatnonzero(raw_share))
    # points of kept classes keep their label
    kept = np.isin(raw.labels, np.flatnonzero(share))
    assert (pruned.labels[kept] == raw.labels[kept]).mean() > 0.99
