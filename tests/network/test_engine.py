"""RandLA-Net's forward pass through OpenVINO (network.randlanet.engine "openvino"): the same
labels as torch, compiled once per crop shape, the export kept in the cache for the next
process."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from jointseg.exceptions import ConfigError
from jointseg.network.randlanet import engine as engine_module
from jointseg.network.randlanet.engine import CompiledForward, openvino_available
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.registry import load
from jointseg.synth import make_room

pytestmark = pytest.mark.skipif(
    not openvino_available(), reason="jointseg[openvino] is not installed"
)


@pytest.fixture(scope="module")
def room():
    return make_room(21, points=60_000)


def test_openvino_labels_a_room_as_torch_does_and_caches_its_export(
    room, tmp_path, monkeypatch
) -> None:
    monkeypatch.setenv("JOINTSEG_CACHE", str(tmp_path))
    plain = load("randlanet")
    fast = load("randlanet", params=RandLANetParams(engine="openvino"))
    assert plain.engine == "torch" and fast.engine == "openvino"
    a = plain.predict(room, seed=0)
    b = fast.predict(room, seed=0)
    assert (a.labels == b.labels).mean() >= 0.995
    assert np.abs(a.probs - b.probs).max() < 1e-3
    exports = sorted((tmp_path / "openvino").glob("randlanet-*.onnx"))
    assert len(exports) == 1  # every crop of the room has the one shape
    stamp = exports[0].stat().st_mtime_ns
    again = load("randlanet", params=RandLANetParams(engine="openvino"))
    c = again.predict(room, seed=0)
    assert (c.labels == b.labels).all()
    assert exports[0].stat().st_mtime_ns == stamp  # read from the cache, not exported again


def test_shapes_beyond_the_compiled_ones_run_on_torch(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(engine_module, "MAX_SHAPES", 0)
    model = load("randlanet").model
    forward = CompiledForward(model, threads=1, folder=tmp_path)
    room = make_room(22, points=20_000)
    net = load("randlanet")
    from jointseg.network.anchored import anchored_cloud

    cloud = anchored_cloud([(room.xyz, room.rgb)], net.grid_size, room.xyz.min(axis=0))
    plan = net.plan(cloud, seed=0)
    batch, _ = next(iter(net._batches(cloud, plan, np.arange(1), 0)))
    args = (batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples)
    with torch.inference_mode():
        assert torch.equal(forward(*args), model(*args))
    assert not list(tmp_path.glob("*.onnx"))  # nothing compiled


def test_the_engine_is_torch_on_a_gpu_and_refused_when_missing(monkeypatch) -> None:
    net = load("randlanet", params=RandLANetParams(engine="openvino"))
    monkeypatch.setattr("jointseg.network.randlanet.predict.openvino_available", lambda: False)
    with pytest.raises(ConfigError, match=r"jointseg\[openvino\]"):
        _ = net.engine
    monkeypatch.setattr(net, "device", torch.device("meta"))
    assert net.engine == "torch"
