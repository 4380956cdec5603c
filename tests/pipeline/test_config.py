"""The pipeline configuration's network section: shared fields plus one section per backend that
takes options, validated by that backend's params model, in the JSON format of old."""

from __future__ import annotations

import pickle

import pytest
from pydantic import ValidationError

from jointseg.network import DGCNNParams
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.registry import REGISTRY
from jointseg.pipeline.config import NetworkConfig, PipelineConfig


def test_each_backend_with_options_has_its_section() -> None:
    sections = {n for n, b in REGISTRY.items() if b.params is not None}
    assert sections == {"dgcnn", "randlanet"}
    fields = set(NetworkConfig.model_fields)
    shared = {"name", "weights", "device", "batch_size", "colour_free", "ensemble"}
    assert fields == shared | sections
    schema = NetworkConfig.model_json_schema()
    assert "used when name is dgcnn" in schema["properties"]["dgcnn"]["description"]
    assert "used when name is randlanet" in schema["properties"]["randlanet"]["description"]


def test_the_chosen_backends_options_come_from_its_section() -> None:
    text = '{"network": {"name": "dgcnn", "dgcnn": {"stride": 1.0, "frame": "scan"}}}'
    config = PipelineConfig.model_validate_json(text)
    assert config.network.options() == DGCNNParams(stride=1.0, frame="scan")
    assert PipelineConfig().network.options() == RandLANetParams()  # the default backend's
    assert config.network.model_dump()["dgcnn"]["stride"] == 1.0
    assert pickle.loads(pickle.dumps(config)) == config  # worker processes receive configs


def test_a_misspelt_backend_option_is_named_whichever_backend_is_chosen() -> None:
    with pytest.raises(ValidationError, match=r"network\.dgcnn\.strid"):
        PipelineConfig.model_validate({"network": {"dgcnn": {"strid": 1.0}}})
    with pytest.raises(ValidationError, match=r"network\.randlanet\.absent_shar"):
        PipelineConfig.model_validate({"network": {"randlanet": {"absent_shar": 0}}})
    with pytest.raises(ValidationError, match=r"network\.pointnet"):
        PipelineConfig.model_validate({"network": {"pointnet": {}}})
