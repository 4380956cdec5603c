"""A few real training steps (never a full training): loss, checkpoint, model card, resume."""

from __future__ import annotations

import pytest
import torch

from jointseg.exceptions import ConfigError
from jointseg.network.checkpoint import load_checkpoint
from jointseg.network.training import augment, class_weights, train


def test_training_steps_write_a_resumable_checkpoint_with_a_card(tmp_path, tiny_training) -> None:
    cfg = tiny_training()
    path = train(cfg)
    model, card, body = load_checkpoint(path)
    assert card["epochs"] == 1 and card["steps"] == 2
    assert "jointseg.synth" in card["data"] and "input_conventions" in card
    assert len(card["history"]) == 1 and card["history"][0]["loss"] > 0
    assert 0.0 <= card["history"][0]["val_miou"] <= 1.0
    assert body["epoch"] == 1 and "optimizer" in body
    resumed = train(tiny_training(epochs=2, out=tmp_path / "m2.pt", resume=path))
    _, card2, body2 = load_checkpoint(resumed)
    assert body2["epoch"] == 2 and [h["epoch"] for h in card2["history"]] == [1, 2]


def test_training_changes_the_weights(tmp_path, tiny_training) -> None:
    torch.manual_seed(0)
    path = train(tiny_training(seed=1))
    trained, _, _ = load_checkpoint(path)
    torch.manual_seed(0)
    from jointseg.network.randlanet import RandLANet, RandLANetConfig

    fresh = RandLANet(RandLANetConfig(num_points=2048))
    diffs = [
        (a - b).abs().max().item()
        for a, b in zip(trained.state_dict().values(), fresh.state_dict().values(), strict=True)
        if a.is_floating_point()
    ]
    assert max(diffs) > 1e-4


def test_class_weights_favour_rare_classes() -> None:
    import numpy as np

    labels = np.array([0] * 900 + [1] * 90 + [2] * 10)
    w = class_weights([labels])
    assert w[2] > w[1] > w[0]


def test_augment_keeps_shapes_and_ranges() -> None:
    import numpy as np

    rng = np.random.default_rng(0)
    xyz = rng.uniform(0, 1, (100, 3)).astype(np.float32)
    rgb = rng.uniform(0, 1, (100, 3)).astype(np.float32)
    x2, r2 = augment(xyz, rgb, rng)
    assert x2.shape == xyz.shape and r2.min() >= 0 and r2.max() <= 1
    # rotation about z keeps heights (up to scaling about the centre and jitter)
    assert np.corrcoef(x2[:, 2], xyz[:, 2])[0, 1] > 0.99


def test_s3dis_folder_without_rooms_is_a_clear_error(tmp_path, tiny_training) -> None:
    with pytest.raises(ConfigError, match="Annotations"):
        train(tiny_training(data=str(tmp_path)))


def test_training_resumes_from_packed_weights(tmp_path, tiny_training) -> None:
    from jointseg.network.checkpoint import pack_checkpoint

    first = train(tiny_training())
    packed = pack_checkpoint(first, tmp_path / "packed.pt")
    resumed = train(tiny_training(epochs=2, out=tmp_path / "again.pt", resume=packed))
    _, card, body = load_checkpoint(resumed)
    assert body["epoch"] == 2 and [h["epoch"] for h in card["history"]] == [1, 2]
