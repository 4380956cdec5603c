"""RandLA-Net's forward pass through OpenVINO (network.randlanet.engine, "auto" by default): the
same labels as torch, compiled once per crop shape, the export kept in the cache for the next
process, run by a forked worker, and torch where OpenVINO cannot run.

OpenVINO's thread pools do not survive a fork, and other tests in this process fork (training
batch workers), so everything that loads OpenVINO runs in a child interpreter of its own.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
import torch

from jointseg.exceptions import ConfigError
from jointseg.network.randlanet.backend import BACKEND
from jointseg.network.randlanet.engine import openvino_available
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.randlanet.predict import RandLANetPredictor, load_randlanet
from tests.support.child_python import in_child

pytestmark = pytest.mark.skipif(
    not openvino_available(), reason="jointseg[openvino] is not installed"
)

SAME_LABELS = """
import json, sys
import numpy as np
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.registry import load
from jointseg.synth import make_room

room = make_room(21, points=20_000)
fast = load("randlanet")  # the default engine
b = fast.predict(room, seed=0)
out = {"engines": [fast.engine], "labels": b.labels[::97].tolist()}
if sys.argv[1:] != ["again"]:  # the second process only reads the cached export
    plain = load("randlanet", params=RandLANetParams(engine="torch"))
    a = plain.predict(room, seed=0)
    out.update(engines=[plain.engine, fast.engine], agree=float((a.labels == b.labels).mean()),
               max_prob_diff=float(np.abs(a.probs - b.probs).max()))
print(json.dumps(out))
"""

SHAPES_BEYOND = """
import json
import numpy as np, torch
from pathlib import Path
from jointseg.network.anchored import anchored_cloud
from jointseg.network.randlanet import engine as engine_module
from jointseg.network.randlanet.engine import CompiledForward
from jointseg.network.registry import load
from jointseg.synth import make_room

engine_module.MAX_SHAPES = 0
net = load("randlanet")
folder = Path(__import__("sys").argv[1])
forward = CompiledForward(net.model, threads=1, folder=folder)
room = make_room(22, points=20_000)
cloud = anchored_cloud([(room.xyz, room.rgb)], net.grid_size, room.xyz.min(axis=0))
plan = net.plan(cloud, seed=0)
batch, _ = next(iter(net.batches(cloud, plan, np.arange(1), 0)))
args = (batch.features, batch.coords, batch.neighbours, batch.pools, batch.upsamples)
with torch.inference_mode():
    # torch's own forward: the same up to the threads' summation order
    same = bool(torch.allclose(forward(*args), net.model(*args), rtol=0, atol=1e-4))
print(json.dumps({"same": same, "exports": len(list(folder.glob("*.onnx")))}))
"""


NO_OPENVINO = """
import json, sys
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.registry import load
from jointseg.synth import make_room

net = load("randlanet", params=RandLANetParams(engine="torch"))
net.predict(make_room(23, points=20_000), seed=0)
print(json.dumps({"engine": net.engine, "openvino_loaded": "openvino" in sys.modules}))
"""


FORKED = """
import json, multiprocessing, sys
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.registry import load
from jointseg.synth import make_room

net = load("randlanet")  # loaded once, as a worker pool's parent does, then forked
room = make_room(24, points=20_000)
if sys.argv[1:] == ["ran"]:  # the parent ran it too: OpenVINO's and torch's pools exist here
    net.predict(room, seed=0)

def work(queue):
    out = net.predict(room, seed=0)
    queue.put({"engine": net.engine, "labels": out.labels.tolist()})

ctx = multiprocessing.get_context("fork")
queue = ctx.Queue()
child = ctx.Process(target=work, args=(queue,))
child.start()
got = queue.get(timeout=240)
child.join(30)
plain = load("randlanet", params=RandLANetParams(engine="torch")).predict(room, seed=0)
agree = sum(a == b for a, b in zip(got["labels"], plain.labels.tolist())) / len(plain.labels)
print(json.dumps({"exit": child.exitcode, "engine": got["engine"], "agree": agree,
                  "parent_loaded_openvino": "openvino" in sys.modules}))
"""

UNUSABLE_CACHE = """
import json
import numpy as np
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.registry import load
from jointseg.synth import make_room

room = make_room(25, points=20_000)
auto = load("randlanet")
a = auto.predict(room, seed=0)
b = load("randlanet", params=RandLANetParams(engine="torch")).predict(room, seed=0)
print(json.dumps({"engine": auto.engine, "same": bool(np.array_equal(a.labels, b.labels))}))
"""


NO_TELEMETRY = """
import json, os, sys
forks = []
os.register_at_fork(before=lambda: forks.append(1))
from jointseg.network.registry import load
from jointseg.synth import make_room

net = load("randlanet")
net.predict(make_room(26, points=20_000), seed=0)
print(json.dumps({"engine": net.engine, "forks": len(forks)}))
"""


@pytest.mark.slow
def test_openvino_labels_a_room_as_torch_does_and_caches_its_export(tmp_path) -> None:
    first = in_child(SAME_LABELS, tmp_path)
    assert first["engines"] == ["torch", "openvino"]
    assert first["agree"] >= 0.995
    assert first["max_prob_diff"] < 1e-3
    exports = sorted((tmp_path / "openvino").glob("randlanet-*.onnx"))
    assert len(exports) == 1  # every crop of the room has the one shape
    stamp = exports[0].stat().st_mtime_ns
    again = in_child(SAME_LABELS, tmp_path, "again")  # no torch run: its labels are known
    assert again["engines"] == ["openvino"] and again["labels"] == first["labels"]
    assert exports[0].stat().st_mtime_ns == stamp  # read from the cache, not exported again


@pytest.mark.slow
def test_shapes_beyond_the_compiled_ones_run_on_torch(tmp_path) -> None:
    out = in_child(SHAPES_BEYOND, tmp_path, str(tmp_path / "ov"))
    assert out == {"same": True, "exports": 0}  # torch's own output, nothing compiled


@pytest.mark.slow
def test_the_default_engine_sends_no_telemetry_and_forks_nothing(tmp_path: Path) -> None:
    """OpenVINO's conversion tools send telemetry from a thread that forks; a fork while the
    geometry thread was inside OpenBLAS left `jointseg segment` spinning forever."""
    out = in_child(NO_TELEMETRY, tmp_path)
    assert out["engine"] == "openvino" and out["forks"] == 0


@pytest.mark.slow
def test_a_forked_worker_runs_the_default_engine(tmp_path: Path) -> None:
    out = in_child(FORKED, tmp_path)
    assert out["exit"] == 0 and out["engine"] == "openvino"
    assert out["agree"] >= 0.995
    assert not out["parent_loaded_openvino"]  # the child compiled for itself


@pytest.mark.slow
def test_a_worker_forked_after_its_parent_ran_the_network_runs_it_on_torch(
    tmp_path: Path,
) -> None:
    """OpenVINO's pool does not survive a fork (such a child hung): the child takes torch, on one
    thread, and gives the same labels."""
    out = in_child(FORKED, tmp_path, "ran")
    assert out["exit"] == 0 and out["engine"] == "torch"
    assert out["agree"] >= 0.995


@pytest.mark.slow
def test_the_default_engine_falls_back_to_torch_when_openvino_cannot_compile(
    tmp_path: Path,
) -> None:
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the cache folder would go")
    out = in_child(UNUSABLE_CACHE, blocker)
    assert out == {"engine": "torch", "same": True}


def torch_predictor(params: RandLANetParams | None = None) -> RandLANetPredictor:
    """The bundled weights in torch's predictor (``load`` may give the compiled one, once this
    process's cache has its export: tests/network/test_compiled.py)."""
    predictor = load_randlanet(BACKEND.bundled, device=None, batch_size=1, params=params)
    assert isinstance(predictor, RandLANetPredictor)
    return predictor


def test_auto_is_openvino_on_the_cpu_torch_where_it_cannot_run(monkeypatch) -> None:
    net = torch_predictor()
    assert net.params.engine == "auto" and net.engine == "openvino"
    monkeypatch.setattr("jointseg.network.randlanet.predict.usable_here", lambda: False)
    assert net.engine == "torch"  # e.g. forked from a process that ran OpenVINO
    monkeypatch.setattr("jointseg.network.randlanet.predict.openvino_available", lambda: False)
    assert net.engine == "torch"


def test_the_engine_is_torch_on_a_gpu_and_refused_when_missing(monkeypatch) -> None:
    net = torch_predictor(RandLANetParams(engine="openvino"))
    monkeypatch.setattr("jointseg.network.randlanet.predict.openvino_available", lambda: False)
    with pytest.raises(ConfigError, match=r"jointseg\[openvino\]"):
        _ = net.engine
    monkeypatch.setattr(net, "device", torch.device("meta"))
    assert net.engine == "torch"


@pytest.mark.slow
def test_the_torch_engine_never_loads_openvino(tmp_path: Path) -> None:
    """A default run must not load OpenVINO: its thread pools do not survive a fork (another
    test in this process may have loaded it through torch's compiler backends, so this is
    checked in a child interpreter)."""
    out = in_child(NO_OPENVINO, tmp_path)
    assert out == {"engine": "torch", "openvino_loaded": False}


def test_training_batches_stay_in_process_once_openvino_is_loaded(monkeypatch) -> None:
    from jointseg.training.batches import batch_stream

    class Maker:
        def __len__(self) -> int:
            return 2

        def __getitem__(self, i: int) -> int:
            return os.getpid() * 10 + i

    monkeypatch.setitem(sys.modules, "openvino", object())  # stands for a loaded OpenVINO
    with batch_stream(Maker(), workers=2, prefetch=False, pin=False) as items:  # type: ignore[arg-type]
        got = list(items)
    assert got == [os.getpid() * 10, os.getpid() * 10 + 1]  # built here, not in forked workers
