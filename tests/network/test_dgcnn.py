"""The DGCNN module: the published layout loads, the fast inference path equals the textbook
formulation, the neighbour search is exact, cancellation reaches inside the forward pass."""

from __future__ import annotations

import pytest
import torch

from jointseg.exceptions import Cancelled
from jointseg.network.dgcnn.model import DGCNN, knn
from jointseg.network.dgcnn.predict import load_dgcnn_state


def brute_force_knn(points: torch.Tensor, k: int) -> torch.Tensor:
    return torch.cdist(points, points).topk(k, dim=-1, largest=False).indices


def test_published_layout_loads_with_and_without_prefix(dgcnn_random_weights) -> None:
    state = torch.load(dgcnn_random_weights, weights_only=True)
    assert all(key.startswith("module.") for key in state)
    assert state["module.conv1.0.weight"].shape == (64, 18, 1, 1)  # 2 x 9 input features
    assert state["module.conv9.weight"].shape == (13, 256, 1)
    model, card = load_dgcnn_state(dgcnn_random_weights)
    # bnX and convX.1 are the same module, as in the reference: both key sets exist
    assert model.bn1 is model.conv1[1]
    assert sum(p.numel() for p in model.parameters()) == 983_552
    assert not model.training
    assert "k=20" in repr(model) and "knn_channels=6:9" in repr(model)
    assert card["data"] == "S3DIS, Area 9 held out"


@pytest.mark.slow
def test_fast_inference_equals_the_plain_formulation(dgcnn_random_weights) -> None:
    model, _ = load_dgcnn_state(dgcnn_random_weights)
    model = model.double()
    torch.manual_seed(1)
    features = torch.rand(2, 512, 9, dtype=torch.float64)
    with torch.inference_mode():
        fast = model(features)
        plain = model._forward_plain(features)
    assert fast.shape == (2, 512, 13)
    torch.testing.assert_close(fast, plain, rtol=1e-9, atol=1e-9)


def test_training_mode_runs_the_plain_formulation_with_gradients() -> None:
    model = DGCNN().train()
    out = model(torch.rand(2, 64, 9))
    out.sum().backward()
    assert out.shape == (2, 64, 13) and model.conv1[0].weight.grad is not None


@pytest.mark.parametrize("dims", [3, 64])  # KD-tree and dense top-k
def test_knn_is_exact_and_includes_the_point_itself(dims: int) -> None:
    torch.manual_seed(dims)
    points = torch.randn(3, 700, dims)
    got = knn(points, 20, chunk=128)
    want = brute_force_knn(points, 20)
    assert got.shape == (3, 700, 20)
    assert torch.equal(got.sort(dim=-1).values, want.sort(dim=-1).values)
    assert (got == torch.arange(700)[None, :, None]).any(dim=-1).all()


def test_forward_checks_between_its_stages(stop_after) -> None:
    model = DGCNN().eval()
    features = torch.rand(1, 64, 9)
    token = stop_after(100)
    with torch.inference_mode():
        model(features, between=token.check)
    assert token.checks == 6
    token = stop_after(2)
    with pytest.raises(Cancelled), torch.inference_mode():
        model(features, between=token.check)
    assert token.checks == 3
