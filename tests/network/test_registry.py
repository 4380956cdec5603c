"""The backend registry: records that import no torch, their options validated by their own
params model, and a backend declared in one module of its own."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from pydantic import BaseModel, ConfigDict

from jointseg.exceptions import ConfigError
from jointseg.network import DGCNNParams, load
from jointseg.network.backends import Backend, _resolve
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.registry import (
    BACKENDS,
    REGISTRY,
    _declared,
    backend_for_suffix,
    has_weights,
    installed_backends,
)


def _imports_torch(code: str) -> bool:
    """Whether running ``code`` in a fresh interpreter leaves torch imported."""
    out = subprocess.run(
        [sys.executable, "-c", f"{code}\nimport sys; print('torch' in sys.modules)"],
        capture_output=True,
        text=True,
        check=True,
    )
    return out.stdout.strip().splitlines()[-1] == "True"


@pytest.mark.slow
def test_the_registry_and_the_backend_records_import_no_torch() -> None:
    assert not _imports_torch(
        "import jointseg.network.registry\n"
        "from jointseg.network import published\n"
        "from jointseg.network.registry import BACKENDS, REGISTRY, resolve_weights\n"
        "from jointseg.network.registry import installed_backends\n"
        "REGISTRY['dgcnn'].options({'stride': 1.0}); resolve_weights('randlanet')\n"
        "installed_backends()"
    )
    # the pipeline's configuration module itself (its package __init__ is not under test here)
    assert not _imports_torch(
        "import sys, types, jointseg\n"
        "pkg = types.ModuleType('jointseg.pipeline')\n"
        "pkg.__path__ = [jointseg.__path__[0] + '/pipeline']\n"
        "sys.modules['jointseg.pipeline'] = pkg\n"
        "from jointseg.pipeline.config import PipelineConfig\n"
        "PipelineConfig.model_validate({'network': {'name': 'dgcnn', 'dgcnn': {'stride': 1}}})"
    )
    assert _imports_torch("from jointseg.network import load, DGCNN")


def test_a_backend_is_installed_when_the_weights_it_would_use_are_there(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, dgcnn_random_weights: Path
) -> None:
    """What the job service refuses jobs by and the job page offers: RandLA-Net's weights are
    bundled; DGCNN's are there once pulled or configured, not when its variable names weights
    that are missing or not pulled yet."""
    monkeypatch.setenv("JOINTSEG_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("JOINTSEG_DGCNN_WEIGHTS", raising=False)
    assert installed_backends() == ("randlanet",)
    assert not has_weights("dgcnn") and not has_weights("pointnet")
    for missing in ("dgcnn-s3dis-2", str(tmp_path / "model_1.t7")):
        monkeypatch.setenv("JOINTSEG_DGCNN_WEIGHTS", missing)
        assert not has_weights("dgcnn")
    monkeypatch.setenv("JOINTSEG_DGCNN_WEIGHTS", str(dgcnn_random_weights))
    assert installed_backends() == ("randlanet", "dgcnn")
    monkeypatch.delenv("JOINTSEG_DGCNN_WEIGHTS")
    pulled = tmp_path / "cache" / "weights" / "dgcnn-s3dis-5.t7"  # where `models pull` puts it
    pulled.parent.mkdir(parents=True)
    pulled.write_bytes(dgcnn_random_weights.read_bytes())
    assert has_weights("dgcnn")


def test_the_records_say_what_each_backend_reads() -> None:
    assert BACKENDS == ("randlanet", "dgcnn") == tuple(REGISTRY)
    bundled = REGISTRY["randlanet"].bundled
    assert bundled is not None and bundled.name == "randlanet_indoor.pt"
    assert REGISTRY["dgcnn"].bundled is None and REGISTRY["dgcnn"].published == "dgcnn-s3dis-5"
    assert [b.env for b in REGISTRY.values()] == [
        "JOINTSEG_RANDLANET_WEIGHTS",
        "JOINTSEG_DGCNN_WEIGHTS",
    ]
    assert [backend_for_suffix(f"w{s}") for s in (".pt", ".pth", ".t7", ".npz")] == [
        "randlanet",
        "randlanet",
        "dgcnn",
        None,
    ]
    assert "jointseg models pull dgcnn-s3dis-5" in REGISTRY["dgcnn"].where_to_get


@pytest.mark.parametrize("name", BACKENDS)
def test_every_loader_and_card_reader_path_names_a_function(name: str) -> None:
    record = REGISTRY[name]
    assert callable(_resolve(record.loader)) and callable(_resolve(record.card_reader))


def test_options_are_validated_by_the_backends_own_model() -> None:
    dgcnn, randlanet = REGISTRY["dgcnn"], REGISTRY["randlanet"]
    assert dgcnn.options() == DGCNNParams()
    assert dgcnn.options({"stride": 1.0}) == DGCNNParams(stride=1.0)
    given = DGCNNParams(num_points=256)
    assert dgcnn.options(given) is given
    with pytest.raises(ConfigError, match="strid"):
        dgcnn.options({"strid": 1.0})
    with pytest.raises(ConfigError, match="takes DGCNNParams"):
        dgcnn.options(_PointNetParams())
    assert randlanet.options() == RandLANetParams()
    assert randlanet.options({"absent_share": 0}) == RandLANetParams(absent_share=0)
    with pytest.raises(ConfigError, match="absent_shar"):
        randlanet.options({"absent_shar": 0})
    bare = dataclasses.replace(randlanet, params=None)  # a backend that takes no options
    assert bare.options() is None and bare.options({}) is None
    with pytest.raises(ConfigError, match="takes no options"):
        bare.options({"stride": 1.0})


def test_load_takes_options_directly_or_under_the_backends_name(dgcnn_random_weights) -> None:
    direct = load("dgcnn", dgcnn_random_weights, device="cpu", params={"num_points": 256})
    assert direct.params == DGCNNParams(num_points=256)  # type: ignore[attr-defined]
    by_name = load("dgcnn", dgcnn_random_weights, device="cpu", dgcnn=DGCNNParams(stride=1.0))
    assert by_name.params == DGCNNParams(stride=1.0)  # type: ignore[attr-defined]
    with pytest.raises(TypeError, match="pointnet"):
        load("dgcnn", dgcnn_random_weights, pointnet={})


class _PointNetParams(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    num_points: int = 2048


def test_a_backend_is_one_module_declaring_its_record(tmp_path, monkeypatch) -> None:
    """What the contributing page's "Adding a backend" shows: a module with ``BACKEND`` and its
    loader."""
    (tmp_path / "pointnet_backend.py").write_text(
        textwrap.dedent(
            """
            from pydantic import BaseModel, ConfigDict
            from jointseg.network.backends import Backend

            class PointNetParams(BaseModel):
                model_config = ConfigDict(extra="forbid", frozen=True)
                num_points: int = 2048

            class PointNetPredictor:
                name = "pointnet"

                def __init__(self, path, device, batch_size, params):
                    self.card = {"data": path.stem}
                    self.batch_size, self.params = batch_size, params

            def load(path, *, device, batch_size, params):
                return PointNetPredictor(path, device, batch_size, params)

            def read_card(path):
                return path.stem, ""

            BACKEND = Backend(
                name="pointnet",
                loader="pointnet_backend:load",
                card_reader="pointnet_backend:read_card",
                env="JOINTSEG_POINTNET_WEIGHTS",
                where_to_get="train them",
                params=PointNetParams,
                params_help="PointNet's sampling",
                suffixes=(".pn",),
            )
            """
        )
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    record = _declared("pointnet_backend")
    assert isinstance(record, Backend) and record.name == "pointnet"
    weights = tmp_path / "area5.pn"
    weights.write_bytes(b"")
    predictor = record.load(weights, device=None, batch_size=2, options={"num_points": 512})
    assert predictor.name == "pointnet" and predictor.card == {"data": "area5"}
    assert predictor.params.num_points == 512  # type: ignore[attr-defined]
    assert record.read_card(Path(weights)) == ("area5", "")
    with pytest.raises(ConfigError, match="num_point"):
        record.options({"num_point": 1})
    monkeypatch.setattr("pointnet_backend.BACKEND", "not a record")
    with pytest.raises(TypeError, match="not a jointseg.network.backends.Backend"):
        _declared("pointnet_backend")
