"""pipeline.run with a small random network: what it returns, that concurrency changes nothing,
progress, cancellation, and that a failing stage stops its sibling."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import torch
from pydantic import ValidationError

from jointseg.exceptions import Cancelled, ConfigError
from jointseg.fusion import FusionParams, fuse
from jointseg.network import NetworkResult
from jointseg.pipeline import (
    OUTPUT_FIELDS,
    PipelineConfig,
    annotate,
    load_predictor,
    report_body,
    run,
)
from jointseg.pipeline.stages import structure_hint
from jointseg.synth import make_room


@pytest.fixture(scope="module")
def room():
    return make_room(3, points=20_000)


@pytest.fixture(scope="module")
def config(random_weights) -> PipelineConfig:
    return PipelineConfig.model_validate(
        {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 2}
    )


@pytest.fixture(scope="module")
def result(room, config):
    return run(room, config)


@pytest.mark.slow
def test_run_returns_every_stage_metrics_and_resolved_params(room, result) -> None:
    n = len(room)
    assert result.network_labels.shape == (n,) and result.network_probs.shape == (n, 13)
    assert result.segments.shape == (n,) and result.segments.dtype == np.int32
    assert result.fused_labels.shape == (n,) and result.fused_labels.dtype == np.int32
    assert result.fused_confidence.dtype == np.float32
    assert ((result.fused_confidence >= 0) & (result.fused_confidence <= 1)).all()
    assert {"load_network", "network", "geometry", "fusion", "metrics", "total"} <= set(
        result.timings
    )
    assert result.metrics is not None and set(result.metrics) == {"network", "fused", "oracle"}
    assert result.metrics["oracle"].miou is not None and result.metrics["oracle"].miou > 0.6
    assert result.params["geometry"]["spacing"] > 0
    assert result.params["geometry"]["cluster_distance"] > 0
    assert result.params["fusion"]["mode"] == FusionParams().mode
    assert result.params["network"]["trained_on"] == "random initialisation (tests)"
    # the fusion stage is fuse() on the two first stages' outputs
    geo = result.geometry
    again = fuse(room.xyz, result.segments, result.network_labels, result.network_probs,
                 main_plane=geo.main_plane, structure=structure_hint(geo))  # fmt: skip
    np.testing.assert_array_equal(again.labels, result.fused_labels)


@pytest.mark.slow
def test_concurrent_and_sequential_runs_agree(room, config, result) -> None:
    sequential = run(room, config.model_copy(update={"concurrent": False}))
    np.testing.assert_array_equal(sequential.network_labels, result.network_labels)
    np.testing.assert_array_equal(sequential.segments, result.segments)
    np.testing.assert_array_equal(sequential.fused_labels, result.fused_labels)


def test_annotate_and_report(room, result) -> None:
    out = annotate(room, result)
    assert set(OUTPUT_FIELDS) <= set(out.fields)
    np.testing.assert_array_equal(out.labels, room.labels)
    body = report_body(room, result, extra_timings={"read": 1.0})
    assert body["points"] == len(room) and body["segments"] == result.geometry.n_segments
    assert body["timings_s"]["total"] == pytest.approx(result.timings["total"] + 1.0)
    iou = body["metrics"]["fused"]["per_class_iou"]
    assert len(iou) == 13 and all(v is None or 0 <= v <= 1 for v in iou.values())
    absent = set(np.arange(13)) - set(np.unique(room.labels)) - set(np.unique(result.fused_labels))
    assert all(iou[name] is None for i, name in enumerate(iou) if i in absent)
    assert body["metrics"]["network"]["miou"] == result.metrics["network"].miou


def test_scan_without_ground_truth_has_no_metrics(room, config) -> None:
    unlabelled = room.subset(np.arange(0, len(room), 2))
    unlabelled = type(room)(unlabelled.xyz, unlabelled.rgb)
    result = run(unlabelled, config)
    assert result.metrics is None
    assert report_body(unlabelled, result)["metrics"] is None


@pytest.mark.slow
def test_progress_reaches_every_stage(room, config) -> None:
    predictor = load_predictor(config.network)
    calls: list[tuple[str, float]] = []
    run(room, config, progress=lambda s, f: calls.append((s, f)), predictor=predictor)
    stages = {s for s, _ in calls}
    assert {"network", "geometry", "fusion"} <= stages
    for stage in ("network", "geometry", "fusion"):
        fractions = [f for s, f in calls if s == stage]
        assert fractions[-1] == 1.0 and all(0 <= f <= 1 for f in fractions)


def test_cancel_during_geometry_stops_the_network_too(room, config) -> None:
    predictor = load_predictor(config.network)
    stop = threading.Event()
    seen_after: list[str] = []

    def progress(stage: str, fraction: float) -> None:
        if stop.is_set():
            seen_after.append(stage)
        if stage == "geometry" and fraction >= 0.2:
            stop.set()

    before = threading.active_count()
    started = time.perf_counter()
    with pytest.raises(Cancelled):
        run(room, config, progress=progress, cancel=stop, predictor=predictor)
    assert time.perf_counter() - started < 60
    assert "fusion" not in seen_after
    assert threading.active_count() == before  # both stage threads have ended


def test_a_preset_cancel_raises_at_once(room, config) -> None:
    stop = threading.Event()
    stop.set()
    with pytest.raises(Cancelled):
        run(room, config, cancel=stop)


class SlowNetwork:
    """A stand-in predictor (the :class:`~jointseg.network.backends.Predictor` protocol) that
    runs until its cancel token is set (or 30 s)."""

    name = "slow"
    card = {"data": "none"}
    device = torch.device("cpu")
    model = None  # no loaded network: the frame stage does not ask it to judge
    batch_size = 1

    def __init__(self) -> None:
        self.stopped_by_token = False

    def predict(self, scan, progress=None, cancel=None, *, seed=0) -> NetworkResult:
        deadline = time.perf_counter() + 30
        while time.perf_counter() < deadline:
            if cancel is not None and cancel.is_set():
                self.stopped_by_token = True
                raise Cancelled("cancelled by request")
            time.sleep(0.01)
        raise AssertionError("the network was never told to stop")


def test_a_failing_stage_stops_its_sibling_and_its_error_propagates(room) -> None:
    # fewer than 10 points: geometry refuses at once, while the network would run on
    tiny = room.subset(np.arange(5))
    network = SlowNetwork()
    started = time.perf_counter()
    with pytest.raises(ConfigError, match="at least 10 points"):
        run(tiny, PipelineConfig(), predictor=network)
    assert network.stopped_by_token
    assert time.perf_counter() - started < 10


def test_config_rejects_unknown_keys_naming_them(random_weights) -> None:
    with pytest.raises(ValidationError, match="netwrok"):
        PipelineConfig.model_validate({"netwrok": {}})
    with pytest.raises(ValidationError, match=r"geometry\.cluster_distanse"):
        PipelineConfig.model_validate({"geometry": {"cluster_distanse": 0.1}})
    with pytest.raises(ValidationError, match=r"fusion\.mode"):
        PipelineConfig.model_validate({"fusion": {"mode": "vote"}})
    overridden = PipelineConfig().with_network(weights=random_weights)
    assert overridden.network.weights == random_weights and overridden.network.name == "randlanet"


def test_missing_weights_and_empty_scans_are_config_errors(room, tmp_path) -> None:
    with pytest.raises(ConfigError, match="no weights"):
        run(room, PipelineConfig().with_network(weights=tmp_path / "none.pt"))
    with pytest.raises(ConfigError, match="no points"):
        run(room.subset(np.zeros(len(room), bool)), predictor=SlowNetwork())
