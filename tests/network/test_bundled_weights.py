"""The weights that ship with the package: small enough, honest about their training (the model
card), and better than chance on a held-out synthetic room."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.metrics import evaluate
from jointseg.network import load
from jointseg.network.randlanet.checkpoint import load_checkpoint
from jointseg.network.registry import REGISTRY
from jointseg.synth import make_room

BUNDLED = REGISTRY["randlanet"].bundled
pytestmark = pytest.mark.skipif(not BUNDLED.is_file(), reason=f"no bundled weights at {BUNDLED}")


def test_bundled_weights_are_small_and_say_what_they_were_trained_on() -> None:
    assert BUNDLED.stat().st_size <= 10_000_000
    _, card, body = load_checkpoint(BUNDLED)
    assert "optimizer" not in body and card["weights_dtype"] == "float16"
    # real rooms, the held-out ones named, synthetic rooms mixed in
    assert "s3dis_area6" in card["data"] and "validation (never trained on)" in card["data"]
    assert "jointseg.synth" in card["data"] and card["synthetic_share"] == 0.2
    assert card["history"] and card["history"][-1]["epoch"] == card["epochs"]
    assert card["validation"]["last_miou"] == card["history"][-1]["val_miou"]
    assert "S3DIS" in card["terms"] and "ScanNet" in card["terms"] and "CPU" in card["hardware"]
    assert "scannet" in card["data"] and set(card["sources"]) == {"a6", "scannet", "synth"}
    assert " train --data " in card["command"]
    # a blend of the handed-over GPU checkpoint and its fine-tuned copy, said so
    assert card["blend"]["base"] == "randlanet_area6_gpu.pt"
    assert 0 < card["blend"]["weight_of_tuned"] < 1
    assert card["input_conventions"]


@pytest.mark.slow
def test_bundled_weights_beat_chance_on_a_held_out_room() -> None:
    scan = make_room(4321, points=40_000, shape="L")  # a seed no training run uses
    labels = load("randlanet", device="cpu").predict(scan).labels
    metrics = evaluate(scan.labels, labels)
    # Chance level: always answering the largest class (mIoU well under 0.1).
    majority = np.bincount(scan.labels[scan.labels >= 0]).max() / np.sum(scan.labels >= 0)
    assert metrics.oa is not None and metrics.oa > majority + 0.2
    assert metrics.miou is not None and metrics.miou > 0.2
