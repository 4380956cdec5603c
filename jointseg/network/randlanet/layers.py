"""RandLA-Net building blocks (Hu et al., CVPR 2020), knowing nothing of datasets.

Tensors are channels-last, (B, N, K, C) and (B, N, C): a shared MLP over points and
neighbours is then one matrix product over the last axis, several times faster on a CPU than
the reference's 1x1 convolution over (B, C, N, K) (8x on the first layers). The parameters
keep the reference's shapes (a 1x1 ``Conv2d``, ``BatchNorm2d``), so checkpoints do not change.
"""

from __future__ import annotations

import torch
from torch import nn

# Running statistics follow the batches within ~20 steps: short CPU trainings are evaluated
# with statistics that match the weights (the reference's 0.01 needs hundreds of steps).
BN_MOMENTUM = 0.1


def batch_norm_last(x: torch.Tensor, bn: nn.BatchNorm2d) -> torch.Tensor:
    """``bn`` over the last axis of a channels-last tensor: the same statistics over every
    other axis, and the same running averages, as the reference's ``BatchNorm2d``."""
    flat = x.reshape(-1, x.shape[-1])
    training = bn.training or bn.running_mean is None
    momentum = 0.0 if bn.momentum is None else bn.momentum
    out = nn.functional.batch_norm(
        flat, bn.running_mean, bn.running_var, bn.weight, bn.bias, training, momentum, bn.eps
    )
    return out.reshape(x.shape)


class SharedMLP(nn.Module):
    """A point-wise linear map (stored as a 1x1 convolution), optional batch norm and
    LeakyReLU, shared by all points and neighbours.

    Shapes
    ------
    input (..., C_in) -> output (..., C_out)
    """

    def __init__(
        self, in_channels: int, out_channels: int, *, bn: bool = True, slope: float | None = 0.2
    ) -> None:
        super().__init__()
        self.in_channels, self.out_channels, self.slope = in_channels, out_channels, slope
        self.conv = nn.Conv2d(in_channels, out_channels, kernel_size=1)
        self.bn = nn.BatchNorm2d(out_channels, eps=1e-6, momentum=BN_MOMENTUM) if bn else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        weight = self.conv.weight.view(self.out_channels, self.in_channels)
        bias = self.conv.bias
        bn = self.bn
        if bn is not None and not bn.training and bn.running_var is not None:
            # inference: the batch norm folded into the linear map, one pass instead of two
            assert bn.running_mean is not None and bias is not None
            scale = torch.rsqrt(bn.running_var + bn.eps)
            if bn.weight is not None:
                scale = scale * bn.weight
            shift = bn.bias if bn.bias is not None else torch.zeros_like(scale)
            weight = weight * scale[:, None]
            bias = (bias - bn.running_mean) * scale + shift
            bn = None
        x = nn.functional.linear(x, weight, bias)
        if bn is not None:
            x = batch_norm_last(x, bn)
        if self.slope is not None:
            x = nn.functional.leaky_relu(x, self.slope)
        return x

    def extra_repr(self) -> str:
        return f"{self.in_channels} -> {self.out_channels}, slope={self.slope}"


def gather_neighbours(values: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """Collect per-neighbour values.

    Shapes
    ------
    values (B, N, C), neighbours (B, M, K) int64 -> (B, M, K, C)
    """
    b, m, k = neighbours.shape
    n, c = values.shape[1], values.shape[2]
    # rows of the flattened batch: one index per neighbour, not one per channel as gather's
    rows = neighbours.reshape(b, m * k)
    if b > 1:
        rows = rows + (torch.arange(b, device=rows.device) * n)[:, None]
    return values.reshape(b * n, c).index_select(0, rows.reshape(-1)).reshape(b, m, k, c)


def relative_position_encoding(coords: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """The 10 geometric channels of local spatial encoding: distance, offset, centre, neighbour.

    Shapes
    ------
    coords (B, N, 3), neighbours (B, N, K) -> (B, N, K, 10)
    """
    k = neighbours.shape[2]
    neighbour_xyz = gather_neighbours(coords, neighbours)
    centre = coords.unsqueeze(2).expand(-1, -1, k, -1)
    offset = centre - neighbour_xyz
    distance = torch.sqrt(torch.sum(offset * offset, dim=3, keepdim=True))
    return torch.cat([distance, offset, centre, neighbour_xyz], dim=3)


class AttentivePooling(nn.Module):
    """Softmax attention over the K neighbours, then a shared MLP.

    Shapes
    ------
    input (B, N, K, C_in) -> output (B, N, C_out)
    """

    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.score = nn.Linear(in_channels, in_channels)
        self.mlp = SharedMLP(in_channels, out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        scores = torch.softmax(self.score(x), dim=2)
        return self.mlp(torch.sum(scores * x, dim=2))


class DilatedResidualBlock(nn.Module):
    """Local feature aggregation: two rounds of local spatial encoding + attentive pooling
    (widening the receptive field), with a residual shortcut.

    Shapes
    ------
    coords (B, N, 3), features (B, N, C_in), neighbours (B, N, K) -> (B, N, 2 * d_out)
    """

    def __init__(self, in_channels: int, d_out: int) -> None:
        super().__init__()
        self.in_channels, self.d_out = in_channels, d_out
        half = d_out // 2
        self.mlp_in = SharedMLP(in_channels, half)
        self.encode1 = SharedMLP(10, half)
        self.pool1 = AttentivePooling(d_out, half)
        self.encode2 = SharedMLP(half, half)
        self.pool2 = AttentivePooling(d_out, d_out)
        self.mlp_out = SharedMLP(d_out, 2 * d_out, slope=None)
        self.shortcut = SharedMLP(in_channels, 2 * d_out, slope=None)

    def forward(
        self, coords: torch.Tensor, features: torch.Tensor, neighbours: torch.Tensor
    ) -> torch.Tensor:
        x = self.mlp_in(features)
        geometry = self.encode1(relative_position_encoding(coords, neighbours))
        x = self.pool1(torch.cat([gather_neighbours(x, neighbours), geometry], 3))
        geometry = self.encode2(geometry)
        x = self.pool2(torch.cat([gather_neighbours(x, neighbours), geometry], 3))
        return nn.functional.leaky_relu(self.mlp_out(x) + self.shortcut(features), 0.01)

    def extra_repr(self) -> str:
        return f"{self.in_channels} -> {2 * self.d_out}"


def random_pool(features: torch.Tensor, pool: torch.Tensor) -> torch.Tensor:
    """Max over the neighbours of the kept points (the first N' of a shuffled crop).

    Shapes
    ------
    features (B, N, C), pool (B, N', K) -> (B, N', C)
    """
    return gather_neighbours(features, pool).max(dim=2).values


def nearest_upsample(features: torch.Tensor, nearest: torch.Tensor) -> torch.Tensor:
    """Copy each fine point's nearest coarse point's features.

    Shapes
    ------
    features (B, N', C), nearest (B, N, 1) -> (B, N, C)
    """
    return gather_neighbours(features, nearest)[:, :, 0, :]
