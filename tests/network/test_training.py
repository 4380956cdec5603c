"""A few real training steps (never a full training): loss, checkpoint, model card, resume."""

from __future__ import annotations

import pytest
import torch

from jointseg.exceptions import ConfigError
from jointseg.network.randlanet.checkpoint import load_checkpoint
from jointseg.training.augment import augment
from jointseg.training.config import class_weights
from jointseg.training.loop import train


@pytest.mark.slow
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


@pytest.mark.slow
def test_training_changes_the_weights(tmp_path, tiny_training) -> None:
    torch.manual_seed(0)
    path = train(tiny_training(seed=1))
    trained, _, _ = load_checkpoint(path)
    torch.manual_seed(0)
    from jointseg.network.randlanet.model import RandLANet, RandLANetConfig

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


@pytest.mark.skipif(torch.cuda.is_available(), reason="needs a machine without CUDA")
def test_cuda_without_cuda_is_a_clear_error(tiny_training) -> None:
    with pytest.raises(ConfigError, match="sees no CUDA device"):
        train(tiny_training(device="cuda"))


def test_s3dis_folder_without_rooms_is_a_clear_error(tmp_path, tiny_training) -> None:
    with pytest.raises(ConfigError, match="Annotations"):
        train(tiny_training(data=str(tmp_path)))


@pytest.mark.slow
def test_training_resumes_from_packed_weights(tmp_path, tiny_training) -> None:
    from jointseg.training.shipping import pack_checkpoint

    first = train(tiny_training())
    packed = pack_checkpoint(first, tmp_path / "packed.pt")
    resumed = train(tiny_training(epochs=2, out=tmp_path / "again.pt", resume=packed))
    _, card, body = load_checkpoint(resumed)
    assert body["epoch"] == 2 and [h["epoch"] for h in card["history"]] == [1, 2]


def test_elastic_distortion_is_smooth_and_small() -> None:
    import numpy as np

    from jointseg.training.augment import ELASTIC_MAGNITUDE, elastic_distortion

    rng = np.random.default_rng(0)
    xyz = rng.uniform(0, 3, (20_000, 3)).astype(np.float32)
    moved = elastic_distortion(xyz, rng)
    shift = np.linalg.norm(moved - xyz, axis=1)
    assert 0.2 * ELASTIC_MAGNITUDE < shift.mean() < 3 * ELASTIC_MAGNITUDE
    assert shift.max() < 10 * ELASTIC_MAGNITUDE
    # a smooth field: two points 1 cm apart move almost alike, points metres apart do not
    near = xyz[:1000] + np.float32(0.01)
    d_near = elastic_distortion(np.vstack([xyz[:1000], near]), np.random.default_rng(5))
    d_near -= np.vstack([xyz[:1000], near])
    gap = np.linalg.norm(d_near[:1000] - d_near[1000:], axis=1)
    assert np.median(gap) < 0.1 * np.median(np.linalg.norm(d_near[:1000], axis=1))


@pytest.mark.slow
def test_prefetched_training_is_the_same_training(tmp_path, tiny_training) -> None:
    """The background thread draws the same batches in the same order: same weights."""
    torch.manual_seed(0)
    ahead = train(tiny_training(out=tmp_path / "ahead.pt", prefetch=True, elastic=0.5))
    torch.manual_seed(0)
    plain = train(tiny_training(out=tmp_path / "plain.pt", prefetch=False, elastic=0.5))
    a, card_a, _ = load_checkpoint(ahead)
    b, card_b, _ = load_checkpoint(plain)
    for (key, x), y in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        assert torch.equal(x, y), key
    assert card_a["history"][0]["loss"] == card_b["history"][0]["loss"]


def test_prefetcher_raises_where_the_batch_failed_and_stops_its_thread() -> None:
    from jointseg.network.batches import Prefetcher, calls

    made: list[int] = []

    def make() -> int:
        made.append(len(made))
        if len(made) == 3:
            raise ValueError("room 3 is broken")
        return made[-1]

    stream = Prefetcher(calls(make, 10), depth=2)
    assert [next(stream), next(stream)] == [0, 1]
    with pytest.raises(ValueError, match="room 3"):
        next(stream)
    with pytest.raises(StopIteration):
        next(stream)
    stream.close()
    assert len(made) == 3  # nothing built after the failure
    slow = Prefetcher(calls(lambda: 1, 1000), depth=1)
    next(slow)
    slow.close()  # the producer, blocked on a full queue, notices and ends
    assert not slow._thread.is_alive()


@pytest.mark.slow
def test_card_says_hardware_command_validation_and_terms(tmp_path, tiny_training) -> None:
    from jointseg.network.backends import card_summary
    from jointseg.training.shipping import pack_checkpoint
    from jointseg.training.sources import S3DIS_TERMS, SYNTH_TERMS

    path = train(tiny_training(epochs=2, command="jointseg train --data synth --out m.pt"))
    _, card, _ = load_checkpoint(path)
    assert "CPU" in card["hardware"] and torch.__version__ in card["hardware"]
    assert card["command"] == "jointseg train --data synth --out m.pt"
    scores = [h["val_miou"] for h in card["history"]]
    assert card["validation"]["best_miou"] == max(scores)
    assert card["validation"]["last_miou"] == scores[-1]
    assert card["terms"] == SYNTH_TERMS and card["synthetic_share"] == 1.0
    # a card written without these facts (older runs) gets them when packed
    model, _, _ = load_checkpoint(path)
    from jointseg.network.randlanet.checkpoint import save_checkpoint

    old = {k: v for k, v in card.items() if k not in ("hardware", "command", "terms")}
    old["train_config"] = {**old["train_config"], "data": "s3dis_rooms/", "command": None}
    save_checkpoint(tmp_path / "old.pt", model, old)
    packed = pack_checkpoint(tmp_path / "old.pt", tmp_path / "ship.pt", command="jointseg x")
    _, shipped, _ = load_checkpoint(packed)
    assert shipped["terms"] == S3DIS_TERMS and shipped["command"] == "jointseg x"
    assert shipped["hardware"].endswith("(recorded when packed)")
    line = card_summary(shipped)
    assert "2 epochs" in line and "validation mIoU" in line and "S3DIS" in line


@pytest.mark.slow
def test_blending_two_checkpoints_interpolates_the_weights(tmp_path, tiny_training) -> None:
    from jointseg.exceptions import ConfigError
    from jointseg.training.shipping import blend_checkpoints

    a = train(tiny_training(out=tmp_path / "a.pt", seed=1))
    b = train(tiny_training(out=tmp_path / "b.pt", seed=2))
    mid = blend_checkpoints(a, b, 0.25, tmp_path / "mid.pt")
    ma, _, _ = load_checkpoint(a)
    mb, _, _ = load_checkpoint(b)
    mm, card, _ = load_checkpoint(mid)
    key = "stem.weight"
    expected = 0.75 * ma.state_dict()[key] + 0.25 * mb.state_dict()[key]
    assert torch.allclose(mm.state_dict()[key].float(), expected, atol=2e-3)
    assert card["blend"]["weight_of_tuned"] == 0.25 and card["blend"]["base"] == "a.pt"
    with pytest.raises(ConfigError, match="blend weight"):
        blend_checkpoints(a, b, 1.5, tmp_path / "bad.pt")
    assert not (tmp_path / "bad.pt").exists()
