"""Fixtures shared by every test package."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from jointseg.network.checkpoint import save_checkpoint
from jointseg.network.dgcnn import DGCNN
from jointseg.network.randlanet import RandLANet, RandLANetConfig


@pytest.fixture(scope="session")
def random_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small, randomly initialised RandLA-Net checkpoint: the tests never need trained weights."""
    torch.manual_seed(0)
    model = RandLANet(RandLANetConfig(num_points=4096))
    path = tmp_path_factory.mktemp("weights") / "random.pt"
    save_checkpoint(path, model, {"data": "random initialisation (tests)"})
    return path


@pytest.fixture(scope="session")
def dgcnn_random_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A randomly initialised DGCNN saved as dgcnn.pytorch saves its S3DIS weights: a state dict
    from ``nn.DataParallel`` (``module.`` prefix), with batch-norm statistics that are not the
    identity, so that folding them is tested."""
    torch.manual_seed(0)
    model = DGCNN()
    for module in model.modules():
        if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
            module.running_mean.uniform_(-0.2, 0.2)
            module.running_var.uniform_(0.5, 2.0)
            module.weight.data.uniform_(-1.5, 1.5)  # negative scales too
            module.bias.data.uniform_(-0.2, 0.2)
    path = tmp_path_factory.mktemp("dgcnn") / "model_9.t7"
    torch.save({f"module.{k}": v for k, v in model.state_dict().items()}, path)
    return path
