"""Self-training's pseudo-labels (issue 65): the pipeline's sure labels on unlabelled scans, a
subset that shrinks as the rule tightens, more often right than the fused labels, written as a
``pseudo/`` source of the prepared run's pack with its manifest entry and terms, and a clear
error (and nothing half-written) for inputs it cannot use."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX
from jointseg.exceptions import ConfigError
from jointseg.io import read_scan, write_scan
from jointseg.network import load
from jointseg.scan import Scan
from jointseg.synth import make_room
from jointseg.synth.views import camera_view
from jointseg.training.loop import train
from jointseg.training.prepared import SHARES, RunOptions, pack, train_config
from jointseg.training.pseudo import (
    Evidence,
    PseudoRule,
    keep_labels,
    pseudo_label,
    segment_share,
)
from jointseg.training.pseudo_pack import PSEUDO, write_pseudo
from jointseg.training.sources import PSEUDO_TERMS, parse_source, terms_for

RULES = [PseudoRule(structure=s, share=a, prob=p) for s in (0.0, 0.5, 0.9)
         for a in (0.0, 0.8, 0.95) for p in (0.0, 0.7, 0.95)]  # fmt: skip


@pytest.fixture(scope="module")
def predictor():
    return load("randlanet")


@pytest.fixture(scope="module")
def labelled(predictor):
    """Two synthetic rooms and a camera view of a third (in the camera's frame, y down),
    pseudo-labelled with their truth hidden: (scan, PseudoScan, truth of the kept points)."""
    scans = [make_room(9100 + i, points=30_000) for i in range(2)]
    view = camera_view(make_room(9102, points=60_000), np.random.default_rng(3))
    assert view is not None
    scans.append(view.scan)
    out = []
    for scan in scans:
        pseudo, result = pseudo_label(scan, PseudoRule(), predictor)
        out.append((scan, pseudo, result, scan.labels[~result.stray]))
    return out


def test_kept_labels_are_fused_labels_and_minus_one_elsewhere(labelled) -> None:
    for _, pseudo, result, _ in labelled:
        fused = result.fused_labels[~result.stray]
        kept = pseudo.labels >= 0
        assert pseudo.labels.dtype == np.int8 and len(pseudo.labels) == len(pseudo.xyz)
        assert 0 < kept.sum() < len(kept)
        assert (pseudo.labels[kept] == fused[kept]).all()
        assert (pseudo.labels[~kept] == -1).all()


def test_a_stricter_rule_keeps_a_subset(labelled) -> None:
    for _, pseudo, _, _ in labelled:
        kept = {r: keep_labels(pseudo.evidence, r) >= 0 for r in RULES}
        for loose in RULES:
            for strict in RULES:
                if all(getattr(strict, k) >= getattr(loose, k) for k in ("structure", "share",
                                                                        "prob")):  # fmt: skip
                    assert not (kept[strict] & ~kept[loose]).any(), (loose, strict)


def test_a_stricter_rule_keeps_a_subset_of_any_evidence() -> None:
    rng = np.random.default_rng(0)
    n = 20_000
    ev = Evidence(
        fused=rng.integers(0, 13, n),
        prob=rng.random(n).astype(np.float32),
        structure=rng.choice([-1, 0, 1, 2], n),
        structure_confidence=rng.random(n).astype(np.float32),
        share=rng.random(n).astype(np.float32),
    )
    for _ in range(50):
        loose = PseudoRule(**dict(zip(("structure", "share", "prob"), rng.random(3), strict=True)))
        tighter = {k: min(1.0, getattr(loose, k) + rng.random() * 0.3) for k in ("structure",
                   "share", "prob")}  # fmt: skip
        strict = PseudoRule(**tighter)
        a, b = keep_labels(ev, loose) >= 0, keep_labels(ev, strict) >= 0
        assert b.sum() <= a.sum() and not (b & ~a).any()


def test_segment_share_counts_each_segments_labels() -> None:
    segments = np.array([5, 5, 5, 5, 9, 9])
    labels = np.array([1, 1, 1, 2, 3, 3])
    assert np.allclose(segment_share(segments, labels), [0.75, 0.75, 0.75, 0.25, 1, 1])


def test_kept_labels_are_more_often_right_than_the_fused_labels(labelled) -> None:
    for _, pseudo, result, truth in labelled:
        fused = result.fused_labels[~result.stray]
        known = truth >= 0
        kept = known & (pseudo.labels >= 0)
        fused_acc = (fused == truth)[known].mean()
        kept_acc = (pseudo.labels == truth)[kept].mean()
        assert kept_acc > fused_acc + 0.05, (kept_acc, fused_acc)


def test_points_are_stored_upright_in_the_pipelines_frame(labelled) -> None:
    _, pseudo, _, truth = labelled[2]  # the camera view: y down, z forward in its file
    floor = pseudo.xyz[truth == CLASS_INDEX["floor"]]
    assert len(floor) > 500
    z = pseudo.xyz[:, 2]
    assert np.ptp(floor[:, 2]) < 0.1 * np.ptp(z)  # the floor is level ...
    assert np.median(floor[:, 2]) < np.quantile(z, 0.02) + 0.05  # ... and at the bottom


@pytest.fixture(scope="module")
def unlabelled_files(tmp_path_factory) -> list[Path]:
    folder = tmp_path_factory.mktemp("unlabelled")
    files = []
    for i, seed in enumerate((9200, 9203)):  # rooms whose floor the structure reading finds
        room = make_room(seed, points=25_000)
        files.append(write_scan(Scan(room.xyz, room.rgb, None), folder / f"site_{i}.ply"))
    return files


def test_the_pack_carries_a_pseudo_source_with_its_manifest_and_terms(
    tmp_path, predictor, unlabelled_files
) -> None:
    data = tmp_path / "data"
    pack(data, None, synth_rooms=1, synth_points=20_000)
    section = write_pseudo(data, unlabelled_files, PseudoRule(), predictor)
    manifest = json.loads((data / "manifest.json").read_text())
    assert manifest["scans"][PSEUDO] == ["site_0", "site_1"]
    assert manifest["terms"][PSEUDO] == PSEUDO_TERMS and "ScanNet" in PSEUDO_TERMS
    assert manifest[PSEUDO]["rule"] == PseudoRule().model_dump()
    for name in ("site_0", "site_1"):
        entry = section["scans"][name]
        scan = read_scan(data / PSEUDO / f"{name}.npz")
        assert len(scan) == entry["points"] and scan.labels is not None
        assert int((scan.labels >= 0).sum()) == entry["kept"] > 0
        assert sum(entry["per_class"].values()) == entry["points"]
        assert entry["source"].endswith(f"{name}.ply")
    # a pack written again keeps the pseudo entry; the prepared run trains on the folder
    pack(data, None, synth_rooms=1, synth_points=20_000)
    assert json.loads((data / "manifest.json").read_text())[PSEUDO] == manifest[PSEUDO]
    opts = RunOptions(data=data, out=tmp_path / "out", steps_per_epoch=1, minutes=0.1)
    cfg = train_config("colour", opts)
    shares = {parse_source(d).name: parse_source(d).share for d in cfg.data}
    assert set(shares) == {"synth", PSEUDO}
    assert shares[PSEUDO] == pytest.approx(SHARES[PSEUDO] / (SHARES[PSEUDO] + SHARES["synth"]),
                                           abs=1e-4)  # fmt: skip
    assert terms_for(parse_source(cfg.data[1])) == PSEUDO_TERMS


@pytest.mark.slow
def test_training_on_pseudo_labels_ignores_the_unsure_points(
    tmp_path, predictor, unlabelled_files, tiny_training
) -> None:
    data = tmp_path / "data"
    write_pseudo(data, unlabelled_files, PseudoRule(), predictor)
    from jointseg.network.randlanet.checkpoint import load_checkpoint

    cfg = tiny_training(data=[f"pseudo={data / PSEUDO}:0.5", "synth:0.5"], val_count=1)
    _, card, _ = load_checkpoint(train(cfg))
    assert np.isfinite(card["history"][-1]["loss"])
    assert PSEUDO_TERMS in card["terms"]


def test_bad_inputs_fail_clearly_and_leave_nothing_half_written(
    tmp_path, predictor, unlabelled_files
) -> None:
    data = tmp_path / "data"
    write_pseudo(data, unlabelled_files[:1], PseudoRule(), predictor)
    before = sorted(p.name for p in (data / PSEUDO).iterdir())
    manifest = (data / "manifest.json").read_text()
    broken = tmp_path / "broken.pcd"
    broken.write_text("not a point cloud\n")
    empty = tmp_path / "empty.ply"
    write_scan(Scan(np.zeros((0, 3))), empty)
    held_out = tmp_path / "scene0002_00.ply"
    held_out.write_bytes(unlabelled_files[0].read_bytes())
    for bad, message in ((broken, "broken.pcd"), (empty, "no points"),
                         (held_out, "judging or validation")):  # fmt: skip
        with pytest.raises(ConfigError, match=message):
            write_pseudo(data, [unlabelled_files[1], bad], PseudoRule(), predictor)
        assert sorted(p.name for p in (data / PSEUDO).iterdir()) == before
        assert (data / "manifest.json").read_text() == manifest
        assert not any(p.name.startswith(".") for p in data.iterdir())
