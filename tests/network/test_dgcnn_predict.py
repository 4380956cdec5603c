"""Whole-scan DGCNN inference: the predict() contract with random weights, the registry's
weights lookup and errors, and the published weights on the real S3DIS fragment."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from jointseg.exceptions import Cancelled, ConfigError
from jointseg.network import DGCNNParams, available_backends, load
from jointseg.network.registry import REGISTRY
from jointseg.scan import Scan
from jointseg.synth import make_room

#: Small samples keep the random-weight tests fast; the block logic is the same at 4 096.
FAST = DGCNNParams(num_points=512)


@pytest.fixture(scope="module")
def room() -> Scan:
    return make_room(1, points=12_000)


def fast_predictor(weights, **kwargs):
    predictor = load("dgcnn", weights, device="cpu", **kwargs)
    predictor.params = FAST
    return predictor


@pytest.mark.slow
def test_predict_labels_every_point(dgcnn_random_weights, room) -> None:
    predictor = fast_predictor(dgcnn_random_weights, batch_size=3)
    result = predictor.predict(room, seed=0)
    n = len(room)
    assert result.labels.shape == (n,) and result.labels.dtype == np.int32
    assert result.probs.shape == (n, 13) and result.probs.dtype == np.float32
    np.testing.assert_allclose(result.probs.sum(axis=1), 1.0, atol=1e-4)
    np.testing.assert_array_equal(result.labels, result.probs.argmax(axis=1))
    assert result.crops >= 1 and set(result.timings) == {"blocks", "blocks_forward", "project"}


@pytest.mark.slow
def test_predict_is_deterministic_and_handles_tiny_and_colourless_scans(
    dgcnn_random_weights, room
) -> None:
    predictor = fast_predictor(dgcnn_random_weights)
    a = predictor.predict(room, seed=4)
    b = predictor.predict(room, seed=4)
    np.testing.assert_array_equal(a.labels, b.labels)
    tiny = room.subset(np.arange(50))  # fewer points than k x 2, one small column
    out = predictor.predict(dataclasses.replace(tiny, rgb=None))
    assert out.labels.shape == (50,)


def test_sparse_coverage_projects_to_unseen_points(dgcnn_random_weights, room) -> None:
    predictor = load("dgcnn", dgcnn_random_weights, device="cpu")
    predictor.params = DGCNNParams(num_points=128, stride=1.0, coverage=0.2)
    result = predictor.predict(room)
    np.testing.assert_allclose(result.probs.sum(axis=1), 1.0, atol=1e-4)
    assert result.crops * 128 < len(room) / 2  # most points were never in a sample


@pytest.mark.slow
def test_progress_and_cancel_inside_the_forward_pass(
    dgcnn_random_weights, room, stop_after
) -> None:
    predictor = fast_predictor(dgcnn_random_weights)
    calls: list[tuple[str, float]] = []
    predictor.predict(room, progress=lambda stage, f: calls.append((stage, f)))
    assert calls[-1] == ("network", 1.0) and calls == sorted(calls)
    token = stop_after(3)  # the batch loop's check, then two stages of the first forward pass
    with pytest.raises(Cancelled):
        predictor.predict(room, cancel=token)
    assert token.checks == 4
    token = stop_after(0)  # set from the start: nothing runs
    with pytest.raises(Cancelled):
        predictor.predict(room, cancel=token)
    assert token.checks == 1


def test_room_size_places_every_block_in_the_middle_of_a_room(dgcnn_random_weights) -> None:
    predictor = load("dgcnn", dgcnn_random_weights, dgcnn=DGCNNParams(room_size=(6.0, 5.0)))
    scan = make_room(2, points=5_000)
    frame = predictor.frame(scan)
    rng = np.random.default_rng(0)
    far = np.array([30.0, 12.0, 0.0])  # a column far along a whole floor
    xyz = np.stack([rng.uniform(0, 1, (64, 3)), far + rng.uniform(0, 1, (64, 3))])
    feats = predictor.sample_features(xyz, np.zeros_like(xyz), frame)
    # x, y normalised around 0.5 wherever the column is; z over the room height
    centre = xyz[..., :2].min(axis=1, keepdims=True) + 0.5
    np.testing.assert_allclose(feats[..., 6:8], 0.5 + (xyz[..., :2] - centre) / [6, 5], atol=1e-6)
    np.testing.assert_allclose(feats[..., 8], xyz[..., 2] / frame.extent[2], atol=1e-6)
    with pytest.raises(ValueError, match="stride 1.5 m exceeds block_size"):
        DGCNNParams(stride=1.5)


def test_missing_weights_say_where_to_get_them(tmp_path, monkeypatch) -> None:
    monkeypatch.delenv(REGISTRY["dgcnn"].env, raising=False)
    monkeypatch.setenv("JOINTSEG_CACHE", str(tmp_path / "empty-cache"))
    with pytest.raises(ConfigError, match="jointseg models pull dgcnn-s3dis-5"):
        load("dgcnn")
    with pytest.raises(ConfigError, match="JOINTSEG_DGCNN_WEIGHTS"):
        load("dgcnn", tmp_path / "model_1.t7")
    info = {b.name: b for b in available_backends()}["dgcnn"]
    assert not info.available and info.weights is None and info.source == "none"
    assert "jointseg models pull dgcnn-s3dis-5" in info.where_to_get


def test_weights_from_the_environment_and_by_suffix(
    dgcnn_random_weights, monkeypatch, tmp_path
) -> None:
    monkeypatch.setenv(REGISTRY["dgcnn"].env, str(dgcnn_random_weights))
    assert load("dgcnn").card["data"] == "S3DIS, Area 9 held out"
    info = {b.name: b for b in available_backends()}["dgcnn"]
    assert info.available and info.weights == dgcnn_random_weights
    assert info.source == "$JOINTSEG_DGCNN_WEIGHTS"
    assert load(str(dgcnn_random_weights)).name == "dgcnn"


def test_foreign_files_are_refused(random_weights, tmp_path) -> None:
    with pytest.raises(ConfigError, match="not a DGCNN S3DIS state dict"):
        load("dgcnn", random_weights)  # a RandLA-Net checkpoint
    other = tmp_path / "other.t7"
    torch.save({"module.conv1.0.weight": torch.zeros(3)}, other)
    with pytest.raises(ConfigError, match="not a DGCNN S3DIS state dict"):
        load("dgcnn", other)
    bad = tmp_path / "bad.t7"
    bad.write_bytes(b"not torch")
    with pytest.raises(ConfigError, match="not a readable PyTorch checkpoint"):
        load("dgcnn", bad)


@pytest.mark.slow
def test_published_weights_on_the_real_fragment(dgcnn_model_1, s3dis_fragment) -> None:
    """Issue 6's check of the input conventions: with the reference's reading (the scan's
    bounding box as the room, 1 m blocks without overlap), model_1 gets the floor right; the
    room frame (the default) repairs what the 1 m slice breaks."""
    from jointseg.io import read_scan
    from jointseg.metrics import evaluate

    scan = read_scan(s3dis_fragment)
    assert scan.labels is not None
    predictor = load("dgcnn", dgcnn_model_1, device="cpu")
    predictor.params = DGCNNParams(frame="scan", stride=1.0)
    reference = evaluate(scan.labels, predictor.predict(scan).labels)
    assert reference.per_class_iou["floor"] >= 0.95 and reference.oa >= 0.55, reference
    predictor.params = DGCNNParams(stride=1.0)
    room = evaluate(scan.labels, predictor.predict(scan).labels)
    assert room.per_class_iou["floor"] >= 0.95, room
    assert room.oa >= reference.oa + 0.1 and room.miou >= reference.miou + 0.05, room
