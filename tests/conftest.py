"""Fixtures shared by every test package."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from jointseg.network.checkpoint import save_checkpoint
from jointseg.network.randlanet import RandLANet, RandLANetConfig


@pytest.fixture(scope="session")
def random_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small, randomly initialised RandLA-Net checkpoint: the tests never need trained weights."""
    torch.manual_seed(0)
    model = RandLANet(RandLANetConfig(num_points=4096))
    path = tmp_path_factory.mktemp("weights") / "random.pt"
    save_checkpoint(path, model, {"data": "random initialisation (tests)"})
    return path
