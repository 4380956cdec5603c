"""Small, randomly initialised RandLA-Net checkpoints: the tests never need trained weights."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from jointseg.network.checkpoint import save_checkpoint
from jointseg.network.randlanet import RandLANet, RandLANetConfig
from jointseg.synth import make_room


@pytest.fixture(scope="session")
def random_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    model = RandLANet(RandLANetConfig(num_points=4096))
    path = tmp_path_factory.mktemp("weights") / "random.pt"
    save_checkpoint(path, model, {"data": "random initialisation (tests)"})
    return path


@pytest.fixture(scope="session")
def small_room():
    return make_room(1, points=30_000)
