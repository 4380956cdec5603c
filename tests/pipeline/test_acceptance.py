"""Issue 5's acceptance, small: with the bundled weights, fusion gains on held-out synthetic
rooms and never loses. Skipped until trained weights are bundled (bench/fusion.py measures the
full version: 10 rooms and 2 floors)."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.network.registry import REGISTRY
from jointseg.pipeline import PipelineConfig, load_predictor, run
from jointseg.synth import make_room

pytestmark = [
    pytest.mark.skipif(
        not REGISTRY["randlanet"].bundled.is_file(),
        reason=f"no bundled weights at {REGISTRY['randlanet'].bundled}",
    ),
    pytest.mark.slow,  # the whole method on held-out rooms of 100 k points
]


def test_default_fusion_gains_on_held_out_rooms_and_never_loses() -> None:
    config = PipelineConfig()
    predictor = load_predictor(config.network)
    gains = []
    for seed, shape in ((5000, "box"), (5001, "L")):
        scan = make_room(seed, points=100_000, shape=shape)
        metrics = run(scan, config, predictor=predictor).metrics
        assert metrics is not None
        network, fused = metrics["network"].miou, metrics["fused"].miou
        assert network is not None and fused is not None
        assert fused >= network, (seed, network, fused)
        gains.append(fused - network)
    assert np.mean(gains) >= 0.02, gains
