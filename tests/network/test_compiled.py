"""The torch-free compiled network (network.randlanet.compiled): once a process has compiled the
bundled weights, the next one labels a scan through the cached export without importing torch,
with the labels the torch-side predictor gives; anything it cannot serve goes to torch.

Everything that runs OpenVINO does so in a child interpreter (its thread pools do not survive
the forks other tests make), each with a cache folder of its own.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from jointseg.network.randlanet.backend import BACKEND
from jointseg.network.randlanet.compiled import CompiledRandLANet
from jointseg.network.randlanet.manifest import MANIFEST_VERSION, manifest_path, read_manifest
from jointseg.network.randlanet.ov_runtime import openvino_available
from jointseg.network.registry import load
from tests.support.child_python import in_child

pytestmark = pytest.mark.skipif(
    not openvino_available(), reason="jointseg[openvino] is not installed"
)

FIRST = """
import json, sys
import numpy as np
from jointseg.network.registry import load
from jointseg.synth import make_room

net = load("randlanet", device="cpu")
out = net.predict(make_room(31, points=20_000), seed=0)
print(json.dumps({"kind": type(net).__name__, "engine": net.engine,
                  "labels": out.labels.tolist(), "probs": out.probs[::7].tolist()}))
"""

SECOND = """
import json, sys
import numpy as np
from jointseg.network.registry import load
from jointseg.synth import make_room

room = make_room(31, points=20_000)
net = load("randlanet", device="cpu")
out = net.predict(room, seed=0)
torch_free = "torch" not in sys.modules
# a tile's share of the same inference, against the torch predictor's
from jointseg.network.anchored import anchored_cloud
lower = room.xyz.min(axis=0)
cloud = anchored_cloud([(room.xyz, room.rgb)], net.grid_size, lower)
plan = net.plan(cloud, seed=0)
crops = np.arange(len(plan))
mine = net.predict_cells(room, plan, lower, crops, seed=0)
theirs = net.torch_predictor().predict_cells(room, plan, lower, crops, seed=0)
print(json.dumps({"kind": type(net).__name__, "engine": net.engine, "torch_free": torch_free,
                  "labels": out.labels.tolist(), "probs": out.probs[::7].tolist(),
                  "same_cells": all(np.array_equal(getattr(mine, f), getattr(theirs, f))
                                    for f in ("ids", "sums", "seen", "point_cell"))}))
"""

CHANGED = """
import json
import torch
from jointseg.network.randlanet.backend import BACKEND
from jointseg.network.randlanet.predict import load_randlanet
from jointseg.synth import make_room

net = load_randlanet(BACKEND.bundled, device="cpu", batch_size=1)
with torch.no_grad():
    next(net.model.parameters()).add_(0.01)  # e.g. a head being fitted in this process
net.predict(make_room(32, points=20_000), seed=0)
print(json.dumps({"engine": net.engine}))
"""

FORKED_AFTER_RUN = """
import json, multiprocessing, sys
from jointseg.network.registry import load
from jointseg.synth import make_room

net = load("randlanet", device="cpu")  # compiled: the first process filled the cache
room = make_room(31, points=20_000)
mine = net.predict(room, seed=0)  # OpenVINO's pool now lives in this process

def work(queue):
    out = net.predict(room, seed=0)
    queue.put({"engine": net.engine, "labels": out.labels.tolist()})

ctx = multiprocessing.get_context("fork")
queue = ctx.Queue()
child = ctx.Process(target=work, args=(queue,))
child.start()
got = queue.get(timeout=240)
child.join(30)
agree = sum(a == b for a, b in zip(got["labels"], mine.labels.tolist())) / len(mine.labels)
print(json.dumps({"kind": type(net).__name__, "exit": child.exitcode, "engine": got["engine"],
                  "agree": agree}))
"""


@pytest.mark.slow
def test_the_next_process_labels_without_torch_as_the_first_did(tmp_path: Path) -> None:
    first = in_child(FIRST, tmp_path)
    assert first["kind"] == "RandLANetPredictor" and first["engine"] == "openvino"
    manifest = read_manifest(BACKEND.bundled, tmp_path / "openvino")
    assert manifest is not None and len(manifest["shapes"]) == 1
    assert manifest["config"]["num_points"] == 8192 and manifest["card"].get("colour") is not False
    second = in_child(SECOND, tmp_path)
    assert second["kind"] == "CompiledRandLANet" and second["engine"] == "openvino"
    assert second["torch_free"]  # the whole prediction ran without importing torch
    assert second["labels"] == first["labels"]
    assert second["probs"] == first["probs"]  # the same sums: one softmax and sum for both
    # a tile's cell sums are the torch predictor's to the last bit: tiles run by either merge
    assert second["same_cells"]


@pytest.mark.slow
def test_a_model_changed_after_reading_is_not_recorded(tmp_path: Path) -> None:
    out = in_child(CHANGED, tmp_path)
    assert out["engine"] == "openvino"
    assert list((tmp_path / "openvino").glob("randlanet-*.onnx"))  # compiled and run
    # ... but the file's manifest would name another model: none is written
    assert not list((tmp_path / "openvino").glob("weights-*.json"))


@pytest.mark.slow
def test_a_child_forked_after_the_compiled_network_ran_labels_on_torch(tmp_path: Path) -> None:
    in_child(FIRST, tmp_path)
    out = in_child(FORKED_AFTER_RUN, tmp_path)
    assert out["kind"] == "CompiledRandLANet"
    assert out["exit"] == 0 and out["engine"] == "torch"  # OpenVINO's pool died in the fork
    assert out["agree"] >= 0.995


@pytest.mark.parametrize(
    "content",
    [
        "not json",
        json.dumps({"version": MANIFEST_VERSION + 1, "config": {}, "shapes": {}}),
        json.dumps({"version": MANIFEST_VERSION, "config": {"k": -1}, "shapes": {}}),
    ],
    ids=["garbage", "newer-version", "invalid-config"],
)
def test_an_unusable_manifest_sends_the_load_to_torch(tmp_path, monkeypatch, content) -> None:
    monkeypatch.setenv("JOINTSEG_CACHE", str(tmp_path))
    path = manifest_path(BACKEND.bundled)
    path.parent.mkdir(parents=True)
    path.write_text(content)
    net = load("randlanet", device="cpu")
    assert type(net).__name__ == "RandLANetPredictor"


def test_views_a_device_or_the_torch_engine_are_left_to_torch(tmp_path, monkeypatch) -> None:
    from jointseg.network.randlanet.params import RandLANetParams

    monkeypatch.setenv("JOINTSEG_CACHE", str(tmp_path))
    path = manifest_path(BACKEND.bundled)
    path.parent.mkdir(parents=True)
    shapes = {"[[1, 8192, 6]]": "randlanet-x.onnx"}
    path.write_text(
        json.dumps(
            {
                "version": MANIFEST_VERSION,
                "config": {"num_points": 8192},
                "card": {},
                "shapes": shapes,
            }
        )  # fmt: skip
    )
    assert isinstance(load("randlanet", device="cpu"), CompiledRandLANet)
    for params, device in [
        (RandLANetParams(views=4), "cpu"),
        (RandLANetParams(engine="torch"), "cpu"),
        (RandLANetParams(), "cuda"),
    ]:
        if device == "cuda":
            from jointseg.network.randlanet.compiled import load_compiled

            compiled = load_compiled(BACKEND.bundled, device=device, batch_size=1, params=params)
            assert compiled is None
            continue
        assert type(load("randlanet", device=device, params=params)).__name__ != "CompiledRandLANet"
