"""Network test data (the random checkpoint ``random_weights`` lives in tests/conftest.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from jointseg.synth import make_room


@pytest.fixture(scope="session")
def small_room():
    return make_room(1, points=30_000)


#: Real scans and published weights shared between checkouts (never copied into the repository).
SHARED = Path(__file__).resolve().parents[2].parent / "shared"


def _shared_file(relative: str) -> Path:
    path = SHARED / relative
    if not path.is_file():
        pytest.skip(f"{path} is not present")
    return path


@pytest.fixture(scope="session")
def s3dis_fragment() -> Path:
    """The real labelled S3DIS fragment; skips when ../shared is absent."""
    return _shared_file("data/s3dis_fragment.ply")


@pytest.fixture(scope="session")
def dgcnn_model_1() -> Path:
    """dgcnn.pytorch's S3DIS weights with Area 1 held out; skips when ../shared is absent."""
    return _shared_file("models/dgcnn_s3dis/model_1.t7")


@pytest.fixture(scope="session")
def dgcnn_random_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A randomly initialised DGCNN saved as dgcnn.pytorch saves its S3DIS weights: a state dict
    from ``nn.DataParallel`` (``module.`` prefix), with batch-norm statistics that are not the
    identity, so that folding them is tested."""
    from jointseg.network.dgcnn import DGCNN

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
