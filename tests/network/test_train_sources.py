"""Training across sources: specs and shares, per-source statistics and validation, worker
processes that give the same batches, and the best checkpoint kept beside the last."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from jointseg.exceptions import ConfigError
from jointseg.io import write_scan
from jointseg.network.randlanet.checkpoint import load_checkpoint
from jointseg.synth import make_room
from jointseg.training.batches import BatchMaker, batch_stream
from jointseg.training.checkpoints import best_path
from jointseg.training.config import training_data
from jointseg.training.loop import train
from jointseg.training.sources import (
    S3DIS_TERMS,
    SCANNET_TERMS,
    SYNTH_TERMS,
    parse_source,
    resolve_shares,
    terms_for,
)


@pytest.fixture(scope="module")
def two_datasets(tmp_path_factory):
    """Two tiny 'datasets': rooms of one kind (ceiling, walls...) and scans where a fifth of the
    points are unlabelled (-1) and re-scans of one room share a prefix."""
    root = tmp_path_factory.mktemp("sources")
    a, b = root / "s3dis_like", root / "scannet_like"
    a.mkdir()
    b.mkdir()
    for seed in range(3):
        write_scan(make_room(700 + seed, points=12_000), a / f"room_{seed}.ply")
    for room in range(3):
        for again in range(2):
            scan = make_room(800 + room, points=12_000)
            labels = scan.labels.copy()
            labels[np.random.default_rng(again).random(len(labels)) < 0.2] = -1
            write_scan(scan.with_fields(labels=labels), b / f"scene{room:04d}_{again:02d}.ply")
    return a, b


def test_source_specs_parse_and_shares_resolve() -> None:
    spec = parse_source("scannet=/data/scans:0.3")
    assert (spec.name, spec.path, spec.share) == ("scannet", "/data/scans", 0.3)
    assert parse_source("/data/s3dis_area6").name == "s3dis_area6"
    assert parse_source("synth:0.2").is_synth
    specs = [parse_source(t) for t in ("a=/x:0.5", "/y", "synth")]
    assert resolve_shares(specs) == [0.5, 0.25, 0.25]
    with pytest.raises(ConfigError, match="add up to 1.2"):
        resolve_shares([parse_source(t) for t in ("/x:0.6", "/y:0.6")])
    with pytest.raises(ConfigError, match="share must be in"):
        parse_source("/x:1.5")
    assert terms_for(parse_source("/data/scannet")) == SCANNET_TERMS
    assert terms_for(parse_source("/data/s3dis_area6")) == S3DIS_TERMS
    assert terms_for(parse_source("synth")) == SYNTH_TERMS


def _config(tiny_training, a, b, **overrides):
    base = dict(
        data=[f"s3dis={a}:0.5", f"scannet={b}:0.3", "synth:0.2"],
        val_scans=["room_2", "scene0001_*"],
        exclude_scans=["scene0002_*"],
        num_points=2048,
        batch_size=2,
    )
    return tiny_training(**{**base, **overrides})


@pytest.mark.slow
def test_mixed_sources_validate_apart_and_keep_judging_scans_out(
    two_datasets, tiny_training
) -> None:
    a, b = two_datasets
    cfg = _config(tiny_training, a, b, epochs=2)
    data = training_data(cfg, 0.04)
    by_name = {s.spec.name: s for s in data.sources}
    assert by_name["scannet"].train_names == ["scene0000_00", "scene0000_01"]
    assert by_name["scannet"].val_names == ["scene0001_00", "scene0001_01"]
    assert by_name["s3dis"].val_names == ["room_2"]
    # draw probabilities give each source its share
    owner = np.repeat([s.spec.name for s in data.sources], [len(s.train) for s in data.sources])
    for src in data.sources:
        assert np.isclose(data.draw_p[owner == src.spec.name].sum(), src.share)
    # class statistics per source; unlabelled points (-1) are not counted
    freq = by_name["scannet"].class_frequency
    assert np.isclose(freq.sum(), 1.0)
    path = train(cfg)
    _, card, _ = load_checkpoint(path)
    assert set(card["history"][-1]["val_by_source"]) == {"s3dis", "scannet", "synth"}
    assert set(card["class_frequency"]) == {"s3dis", "scannet", "synth"}
    assert SCANNET_TERMS in card["terms"] and S3DIS_TERMS in card["terms"]
    assert "scene0002" not in card["data"]


@pytest.mark.slow
def test_the_best_checkpoint_is_kept_beside_the_last(two_datasets, tiny_training) -> None:
    a, b = two_datasets
    path = train(_config(tiny_training, a, b, epochs=3, lr=0.05))
    _, last, _ = load_checkpoint(path)
    best, best_card, body = load_checkpoint(best_path(path))
    scores = [h["val_miou"] for h in last["history"]]
    assert best_card["best_of_run"] and scores[body["epoch"] - 1] == max(scores)
    assert best_card["history"][-1]["val_miou"] == max(scores)


def _maker(tiny_training, a, b, count=4):
    cfg = _config(tiny_training, a, b)
    data = training_data(cfg, 0.04)
    from jointseg.network.randlanet.model import RandLANetConfig

    return BatchMaker(
        data.clouds,
        data.draw_p,
        data.centre_p,
        RandLANetConfig(num_points=2048),
        cfg.augmentation(),
        batch_size=2,
        num_points=2048,
        seed=7,
        count=count,
    )


def test_workers_give_the_same_batches_for_any_number(two_datasets, tiny_training) -> None:
    a, b = two_datasets
    maker = _maker(tiny_training, a, b)
    runs = []
    for workers in (0, 1, 2, 2):
        with batch_stream(maker, workers=workers, prefetch=False, pin=False) as batches:
            runs.append([(x.features.clone(), x.labels.clone(), x.neighbours[2]) for x in batches])
    for other in runs[1:]:
        assert len(other) == len(runs[0]) == 4
        for (f0, l0, n0), (f1, l1, n1) in zip(runs[0], other, strict=True):
            assert torch.equal(f0, f1) and torch.equal(l0, l1) and torch.equal(n0, n1)
    # and batches differ from one another (a stream of one batch repeated would pass above)
    assert not torch.equal(runs[0][0][0], runs[0][1][0])
    # a resumed run continues with the batches it would have drawn
    maker.first, maker.count = 2, 2
    with batch_stream(maker, workers=1, prefetch=False, pin=False) as batches:
        resumed = [x.features for x in batches]
    assert torch.equal(resumed[0], runs[0][2][0])


def test_bad_sources_are_clear_errors(two_datasets, tiny_training, tmp_path) -> None:
    a, b = two_datasets
    with pytest.raises(ConfigError, match="not in any training folder: nope_"):
        train(_config(tiny_training, a, b, val_scans=["nope_*"]))
    with pytest.raises(ConfigError, match="names repeat"):
        train(tiny_training(data=[str(a), str(a)]))
    with pytest.raises(ConfigError, match="every scan is excluded"):
        train(tiny_training(data=[str(a)], exclude_scans=["room_*"]))
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="empty folder"):
        train(tiny_training(data=[str(tmp_path / "empty")]))


@pytest.mark.slow
def test_neighbours_on_the_device_train_as_the_workers_do(two_datasets, tiny_training) -> None:
    """Crops sent bare and searched on the training device (the GPU path, here on the CPU) give
    the same steps as batches the workers complete."""
    a, b = two_datasets
    losses = []
    for on_device in (False, True):
        torch.manual_seed(0)
        cfg = _config(
            tiny_training, a, b, neighbours_on_device=on_device, workers=1, steps_per_epoch=1
        )
        _, card, _ = load_checkpoint(train(cfg))
        losses.append(card["history"][0]["loss"])
    assert losses[0] == pytest.approx(losses[1], rel=1e-4)
