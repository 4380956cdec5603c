"""The crop bank (issue 65): crops and their layers' indices drawn once, stored, read per step."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from jointseg.exceptions import ConfigError
from jointseg.network.randlanet.checkpoint import load_checkpoint
from jointseg.network.randlanet.crops import build_batch
from jointseg.network.randlanet.model import RandLANetConfig
from jointseg.training import bank as bank_module
from jointseg.training.augment import StepAugment
from jointseg.training.bank import (
    CropBank,
    _Drawer,
    bank_spec,
    build_bank,
    layer_sizes,
    read_manifest,
)
from jointseg.training.bank_batches import BankBatches, augment_xyz, bank_batch
from jointseg.training.config import TrainConfig, training_data
from jointseg.training.loop import train
from tests.support.cli import run_cli

POINTS = 2048
CROPS = 5


def tiny(tmp: Path, **overrides: object) -> TrainConfig:
    base: dict[str, object] = dict(
        out=tmp / "m.pt",
        num_points=POINTS,
        synth_rooms=1,
        synth_floors=0,
        val_rooms=1,
        synth_points=20_000,
        threads=1,
    )
    return TrainConfig(**{**base, **overrides})  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def built(tmp_path_factory: pytest.TempPathFactory) -> tuple[TrainConfig, Path]:
    """A bank of five crops in shards of two, drawn by two worker processes."""
    root = tmp_path_factory.mktemp("bank")
    cfg = tiny(root)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bank_module, "SHARD_CROPS", 2)
        build_bank(cfg, root / "bank", CROPS, max_bytes=10**9, workers=2)
    return cfg, root / "bank"


def records(folder: Path) -> list[np.void]:
    bank = CropBank(folder)
    return [bank.record(j) for j in range(len(bank))]


def test_bank_crops_hold_build_batchs_indices_exactly(built) -> None:
    cfg, folder = built
    bank = CropBank(folder)
    manifest = bank.manifest
    assert manifest.crops == CROPS and [s.crops for s in manifest.shards] == [2, 2, 1]
    assert manifest.bytes == sum((folder / s.name).stat().st_size for s in manifest.shards)
    assert manifest.bytes < CROPS * (manifest.bytes_per_crop + 4096)
    data = training_data(cfg, 0.04)
    drawer = _Drawer(bank.spec, data.clouds, data.draw_p, data.centre_p)
    sizes = layer_sizes(POINTS, bank.spec.ratios)
    net = RandLANetConfig(num_points=POINTS)
    for j in (0, 3, 4):
        rec = bank.record(j)
        crop = drawer.crop(j)  # the crop j the trainer's drawing gives, again
        np.testing.assert_array_equal(rec["xyz"], crop.xyz)
        np.testing.assert_array_equal(rec["labels"], crop.labels)
        assert np.abs(rec["rgb"].astype(np.float32) - crop.rgb).max() < 1e-3
        got = bank_batch([rec], sizes, None, StepAugment())
        rgb = np.asarray(rec["rgb"], dtype=np.float32)
        want = build_batch([(crop.xyz, rgb, crop.labels, np.arange(POINTS))], net)
        for name in ("coords", "neighbours", "pools", "upsamples"):
            for a, b in zip(getattr(got, name), getattr(want, name), strict=True):
                assert a.shape == b.shape and a.dtype == b.dtype, name
                assert bool((a == b).all()), name
        assert bool((got.features == want.features).all())
        assert got.labels is not None and want.labels is not None
        assert torch.equal(got.labels, want.labels)


def knn_agreement(coords: np.ndarray, stored: np.ndarray, k: int) -> float:
    """Share of points whose stored neighbours are the k nearest of ``coords`` (points where
    the k-th and (k+1)-th distances tie to 1e-5 count as agreeing)."""
    dist, idx = cKDTree(coords).query(coords, k=k + 1)
    same = np.array([set(a) == set(b) for a, b in zip(idx[:, :k], stored, strict=True)])
    tie = np.abs(dist[:, k] - dist[:, k - 1]) <= 1e-5 * np.maximum(dist[:, k], 1e-9)
    return float((same | tie).mean())


def test_step_augmentations_keep_every_layers_neighbours(built) -> None:
    _, folder = built
    bank = CropBank(folder)
    sizes = layer_sizes(POINTS, bank.spec.ratios)
    aug = StepAugment(mirror=1.0, scale=(0.8, 1.2))
    batch = BankBatches(bank, 2, seed=4, aug=aug, count=3)
    for item in range(3):
        b = batch[item]
        for layer in range(len(sizes) - 2):  # the deepest layers hold fewer than k+1 points
            for crop in range(2):
                coords = b.coords[layer][crop].numpy().astype(np.float64)
                stored = b.neighbours[layer][crop].numpy()
                assert knn_agreement(coords, stored, bank.spec.k) == 1.0, (item, layer)
        # the step's rotation did move the points: the first layer's coordinates differ
        plain = bank_batch([bank.record(0)], sizes, None, aug).coords[0][0].numpy()
        assert np.abs(b.coords[0][0].numpy() - plain).max() > 0.01
    # control: an anisotropic scale (which the steps never draw) does change neighbours
    pts = bank_batch([bank.record(0)], sizes, None, aug).coords[0][0].numpy().astype(np.float64)
    rng = np.random.default_rng(0)
    rotated = augment_xyz(pts.astype(np.float32), rng, aug).astype(np.float64)
    stored = bank_batch([bank.record(0)], sizes, None, aug).neighbours[0][0].numpy()
    assert knn_agreement(rotated, stored, bank.spec.k) == 1.0
    assert knn_agreement(pts * [2.0, 1.0, 0.5], stored, bank.spec.k) < 0.9


def test_a_build_beyond_the_bound_is_refused_and_writes_nothing(built, tmp_path) -> None:
    cfg, folder = built
    per_crop = read_manifest(folder).bytes_per_crop  # type: ignore[union-attr]
    with pytest.raises(ConfigError, match=r"beyond the bound of .*at most about 3 crops fit"):
        build_bank(cfg, tmp_path / "b", 50, max_bytes=3 * per_crop + 4096, workers=1)
    assert not list((tmp_path / "b").iterdir())
    # extending an existing bank past its bound: refused, the bank as it was
    copy = tmp_path / "copy"
    copy.mkdir()
    for path in folder.iterdir():
        (copy / path.name).write_bytes(path.read_bytes())
    before = sorted(p.name for p in copy.iterdir())
    with pytest.raises(ConfigError, match="beyond the bound"):
        build_bank(cfg, copy, CROPS + 40, max_bytes=(CROPS + 2) * per_crop, workers=1)
    assert sorted(p.name for p in copy.iterdir()) == before
    assert read_manifest(copy).crops == CROPS  # type: ignore[union-attr]


def test_an_interrupted_build_leaves_no_half_shard_and_resumes_to_the_same_bank(
    built, tmp_path, monkeypatch
) -> None:
    cfg, folder = built
    monkeypatch.setattr(bank_module, "SHARD_CROPS", 2)
    target = tmp_path / "b"
    build_bank(cfg, target, 2, max_bytes=10**9, workers=1)  # one shard
    real_save = np.save

    def torn(fh, arr) -> None:  # writes half a shard, then the build is cut off
        fh.write(b"\x93NUMPY" + b"\0" * 1000)
        raise KeyboardInterrupt

    monkeypatch.setattr(bank_module.np, "save", torn)
    with pytest.raises(KeyboardInterrupt):
        build_bank(cfg, target, CROPS, max_bytes=10**9, workers=1)
    monkeypatch.setattr(bank_module.np, "save", real_save)
    names = sorted(p.name for p in target.iterdir())
    assert names == ["manifest.json", "shard_000000000.npy"]
    assert read_manifest(target).crops == 2  # type: ignore[union-attr]
    # a stray shard renamed into place before the manifest listed it is dropped on resume
    (target / "shard_000000002.npy").write_bytes(b"junk")
    build_bank(cfg, target, CROPS, max_bytes=10**9, workers=1)  # resumed: extended to five
    assert read_manifest(target).crops == CROPS  # type: ignore[union-attr]
    for a, b in zip(records(target), records(folder), strict=True):
        for field in ("xyz", "rgb", "labels", "neighbours", "upsamples"):
            np.testing.assert_array_equal(a[field], b[field])


def test_a_bank_of_other_crops_is_not_extended(built) -> None:
    cfg, folder = built
    other = cfg.model_copy(update={"seed": 9})
    assert bank_spec(other) != bank_spec(cfg)
    with pytest.raises(ConfigError, match="seed: 0 there, 9 here"):
        build_bank(other, folder, CROPS + 1, max_bytes=10**9, workers=1)


@pytest.mark.slow
def test_training_from_a_bank_lowers_the_loss_and_resumes(built, tmp_path) -> None:
    _, folder = built
    cfg = tiny(tmp_path, bank=folder, epochs=3, steps_per_epoch=4, batch_size=2, lr=0.01)
    path = train(cfg)
    _, card, body = load_checkpoint(path)
    losses = [h["loss"] for h in card["history"]]
    assert losses[-1] < losses[0], losses
    assert card["bank"]["crops"] == CROPS and card["bank"]["path"] == folder.name
    assert card["train_config"]["bank"] == folder.name and "crops from the bank" in card["data"]
    resumed = train(tiny(tmp_path, bank=folder, epochs=4, steps_per_epoch=4, batch_size=2,
                         out=tmp_path / "r.pt", resume=path))  # fmt: skip
    assert load_checkpoint(resumed)[2]["epoch"] == 4


def test_a_bank_of_other_crops_sizes_is_refused(built, tmp_path) -> None:
    _, folder = built
    with pytest.raises(ConfigError, match="--num-points 2048"):
        train(tiny(tmp_path, bank=folder, num_points=4096))


@pytest.mark.slow
def test_jointseg_train_builds_a_bank_and_trains_from_it(tmp_path) -> None:
    out, bank = tmp_path / "m.pt", tmp_path / "bank"
    result = run_cli(
        "train", "--data", "synth", "--synth-rooms", "1", "--synth-floors", "0",
        "--synth-val-rooms", "1", "--epochs", "1", "--steps", "2", "--batch-size", "2",
        "--num-points", "2048", "--threads", "1", "--out", str(out),
        "--bank", str(bank), "--bank-crops", "4", "--bank-gb", "0.01",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    manifest = read_manifest(bank)
    assert manifest is not None and manifest.crops == 4 and manifest.bytes < 10**7
    card = load_checkpoint(out)[1]
    assert card["bank"]["crops"] == 4 and "--bank-crops" in card["command"]
    # a bank too large for its bound is a one-line refusal
    result = run_cli(
        "train", "--data", "synth", "--synth-rooms", "1", "--synth-floors", "0",
        "--synth-val-rooms", "1", "--out", str(tmp_path / "n.pt"), "--bank", str(bank),
        "--bank-crops", "400",
        "--bank-gb", "0.01", "--num-points", "2048",
    )  # fmt: skip
    assert result.returncode == 2 and "beyond the bound" in result.stderr
    assert "Traceback" not in result.stderr and read_manifest(bank).crops == 4  # type: ignore[union-attr]


@pytest.mark.slow
def test_the_prepared_run_trains_the_colour_free_network_from_a_colour_bank(tmp_path) -> None:
    from jointseg.training import prepared

    data = tmp_path / "data"
    prepared.pack(data, None, synth_rooms=2, synth_points=40_000)
    bank = tmp_path / "bank"
    assert prepared.main(["bank", "--data", str(data), "--out", str(bank), "--crops", "3",
                          "--num-points", "2048", "--workers", "1"]) == 0  # fmt: skip
    assert read_manifest(bank).spec.colour  # type: ignore[union-attr]
    opts = prepared.RunOptions(data=data, out=tmp_path / "out", device="cpu", bank=bank)
    opts.out.mkdir()
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("JOINTSEG_GPU_WORK", str(tmp_path / "work"))
        cfg = prepared.train_config("nocolour", opts)
        assert (cfg.bank, cfg.batch_size, cfg.num_points) == (bank, prepared.BANK_BATCH, 2048)
        assert cfg.workers == 0 and not cfg.colour
        cfg = cfg.model_copy(update={"epochs": 1, "steps_per_epoch": 1, "batch_size": 2})
        card = load_checkpoint(train(cfg))[1]
    assert card["bank"]["crops"] == 3 and card["colour"] is False
    # a colour-free bank cannot train a colour network
    nocolour = tmp_path / "nocolour"
    build_bank(tiny(tmp_path, colour=False), nocolour, 1, max_bytes=10**9, workers=1)
    with pytest.raises(ConfigError, match="drawn without colour"):
        train(tiny(tmp_path, bank=nocolour))
