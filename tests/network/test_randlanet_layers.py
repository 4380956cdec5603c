"""The channels-last RandLA-Net layers compute what the reference's (B, C, N, K) layout does."""

from __future__ import annotations

import torch
from torch import nn

from jointseg.network.randlanet.layers import (
    SharedMLP,
    batch_norm_last,
    gather_neighbours,
    nearest_upsample,
)


def test_gather_neighbours_picks_each_batch_items_own_rows() -> None:
    torch.manual_seed(0)
    values = torch.randn(3, 50, 7)
    neighbours = torch.randint(0, 50, (3, 20, 4))
    out = gather_neighbours(values, neighbours)
    want = torch.stack([values[b][neighbours[b]] for b in range(3)])  # (3, 20, 4, 7)
    assert out.shape == (3, 20, 4, 7) and torch.equal(out, want)
    up = nearest_upsample(values, neighbours[:, :, :1])
    assert torch.equal(up, want[:, :, 0, :])


def test_shared_mlp_in_inference_equals_the_reference_convolution_and_batch_norm() -> None:
    torch.manual_seed(1)
    mlp = SharedMLP(6, 9)
    assert mlp.bn is not None
    with torch.no_grad():  # statistics that are not the identity
        mlp.bn.running_mean.uniform_(-1, 1)
        mlp.bn.running_var.uniform_(0.5, 2)
        mlp.bn.weight.uniform_(0.5, 1.5)
        mlp.bn.bias.uniform_(-1, 1)
    mlp.eval()
    x = torch.randn(2, 30, 5, 6)  # channels last
    reference = nn.functional.leaky_relu(mlp.bn(mlp.conv(x.permute(0, 3, 1, 2))), 0.2)
    assert torch.allclose(mlp(x), reference.permute(0, 2, 3, 1), atol=1e-5)


def test_training_batch_norm_keeps_the_reference_running_statistics() -> None:
    torch.manual_seed(2)
    ours, theirs = nn.BatchNorm2d(4, momentum=0.1), nn.BatchNorm2d(4, momentum=0.1)
    x = torch.randn(2, 4, 30, 5) * 3 + 1  # (B, C, N, K)
    out = batch_norm_last(x.permute(0, 2, 3, 1), ours)
    ref = theirs(x)
    assert torch.allclose(out, ref.permute(0, 2, 3, 1), atol=1e-5)
    assert torch.allclose(ours.running_mean, theirs.running_mean)
    assert torch.allclose(ours.running_var, theirs.running_var)
    assert not torch.allclose(ours.running_mean, torch.zeros(4))
