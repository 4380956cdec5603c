"""RandLA-Net building blocks (Hu et al., CVPR 2020), knowing nothing of datasets.

Tensors keep the (B, C, N, K) layout of the reference implementation so that 1x1 convolutions
act as shared MLPs over points (N) and neighbours (K).
"""

from __future__ import annotations

import torch
from torch import nn

# Running statistics follow the batches within ~20 steps: short CPU trainings are evaluated
# with statistics that match the weights (the reference's 0.01 needs hundreds of steps).
BN_MOMENTUM = 0.1


class SharedMLP(nn.Module):
    """1x1 convolution, optional batch norm and LeakyReLU, shared by all points.

    Shapes
    ------
    input (B, C_in, N, K) -> output (B, C_out, N, K)
    """

    def __init__(
        self, in_channels: int, out_channels: int, *, bn: bool = True, slope: float | None = 0.2
    ) -> None:
        super().__init__()
        self.in_channels, self.out_channels, self.slope = in_channels, out_channels, slope
        self.conv = nn.Conv2d(in_channels, out_channels, kernel_size=1)
        self.bn = nn.BatchNorm2d(out_channels, eps=1e-6, momentum=BN_MOMENTUM) if bn else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.conv(x)
        if self.bn is not None:
            x = self.bn(x)
        if self.slope is not None:
            x = nn.functional.leaky_relu(x, self.slope)
        return x

    def extra_repr(self) -> str:
        return f"{self.in_channels} -> {self.out_channels}, slope={self.slope}"


def gather_neighbours(values: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """Collect per-neighbour values.

    Shapes
    ------
    values (B, N, C), neighbours (B, M, K) int64 -> (B, C, M, K)
    """
    b, m, k = neighbours.shape
    c = values.shape[2]
    flat = neighbours.reshape(b, m * k, 1).expand(b, m * k, c)
    picked = torch.gather(values, 1, flat)  # (B, M*K, C)
    return picked.reshape(b, m, k, c).permute(0, 3, 1, 2)


def relative_position_encoding(coords: torch.Tensor, neighbours: torch.Tensor) -> torch.Tensor:
    """The 10 geometric channels of local spatial encoding: distance, offset, centre, neighbour.

    Shapes
    ------
    coords (B, N, 3), neighbours (B, N, K) -> (B, 10, N, K)
    """
    k = neighbours.shape[2]
    neighbour_xyz = gather_neighbours(coords, neighbours)
    centre = coords.transpose(1, 2).unsqueeze(-1).expand(-1, -1, -1, k)
    offset = centre - neighbour_xyz
    distance = torch.sqrt(torch.sum(offset * offset, dim=1, keepdim=True))
    return torch.cat([distance, offset, centre, neighbour_xyz], dim=1)


class AttentivePooling(nn.Module):
    """Softmax attention over the K neighbours, then a shared MLP.

    Shapes
    ------
    input (B, C_in, N, K) -> output (B, C_out, N, 1)
    """

    def __init__(self, in_channels: int, out_channels: int) -> None:
        super().__init__()
        self.score = nn.Linear(in_channels, in_channels)
        self.mlp = SharedMLP(in_channels, out_channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # The Linear's weights applied as a 1x1 convolution: same parameters (and checkpoints)
        # as the reference, without permuting the (B, C, N, K) tensor there and back.
        weight = self.score.weight[:, :, None, None]
        scores = torch.softmax(nn.functional.conv2d(x, weight, self.score.bias), dim=3)
        return self.mlp(torch.sum(scores * x, dim=-1, keepdim=True))


class DilatedResidualBlock(nn.Module):
    """Local feature aggregation: two rounds of local spatial encoding + attentive pooling
    (widening the receptive field), with a residual shortcut.

    Shapes
    ------
    coords (B, N, 3), features (B, C_in, N, 1), neighbours (B, N, K) -> (B, 2 * d_out, N, 1)
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
        x = torch.cat([gather_neighbours(x.squeeze(3).transpose(1, 2), neighbours), geometry], 1)
        x = self.pool1(x)
        geometry = self.encode2(geometry)
        x = torch.cat([gather_neighbours(x.squeeze(3).transpose(1, 2), neighbours), geometry], 1)
        x = self.pool2(x)
        return nn.functional.leaky_relu(self.mlp_out(x) + self.shortcut(features), 0.01)

    def extra_repr(self) -> str:
        return f"{self.in_channels} -> {2 * self.d_out}"


def random_pool(features: torch.Tensor, pool: torch.Tensor) -> torch.Tensor:
    """Max over the neighbours of the kept points (the first N' of a shuffled crop).

    Shapes
    ------
    features (B, C, N, 1), pool (B, N', K) -> (B, C, N', 1)
    """
    gathered = gather_neighbours(features.squeeze(3).transpose(1, 2), pool)
    return gathered.max(dim=3, keepdim=True).values


def nearest_upsample(features: torch.Tensor, nearest: torch.Tensor) -> torch.Tensor:
    """Copy each fine point's nearest coarse point's features.

    Shapes
    ------
    features (B, C, N', 1), nearest (B, N, 1) -> (B, C, N, 1)
    """
    b, c = features.shape[:2]
    idx = nearest.reshape(b, 1, -1).expand(b, c, -1)
    return torch.gather(features.squeeze(3), 2, idx).unsqueeze(3)
