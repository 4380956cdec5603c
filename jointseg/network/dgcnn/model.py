"""DGCNN for semantic segmentation (Wang et al., *Dynamic Graph CNN for Learning on Point
Clouds*, 2019), laid out so the public S3DIS state dicts of antao97/dgcnn.pytorch load as they are.

Three EdgeConv layers (the first over a k-NN graph of the room-normalised coordinates, the next
two over graphs rebuilt in feature space), a 1024-d global feature by max pooling over the block,
and a per-point head. Parameter names follow the published checkpoints: ``conv1`` … ``conv8``
are ``Sequential(conv, bn, LeakyReLU(0.2))`` whose batch norms are also reachable as ``bn1`` …
``bn8`` (the same modules, so both key sets of the state dict load), ``conv9`` is the classifier.

Inference (eval mode) uses algebra that gives the same result at a fraction of the work:

- an EdgeConv's first 1x1 convolution on ``[x_j - x_i, x_i]`` is ``W_a x_j + (W_b - W_a) x_i``,
  so it runs once per point instead of once per edge (k = 20 times fewer multiplications);
- eval-mode batch norm is an affine map, folded into the convolution before it;
- where the max over neighbours follows directly (third EdgeConv, global pooling), it is taken
  before the monotone LeakyReLU;
- the head's first convolution on ``[global repeated, local]`` splits into one product per block
  for the global part and one per point for the local part.

Training mode runs the plain formulation (edge tensors, batch statistics) instead.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn
from torch.nn import functional
from torch.nn.modules.batchnorm import _BatchNorm

SLOPE = 0.2  # LeakyReLU slope of every layer
#: Query rows per chunk of the dense distance computation: a (B, chunk, N) block of scores
#: exists at a time, never the whole (B, N, N) matrix (256 rows keep it in cache).
KNN_CHUNK = 256
#: Up to this many dimensions, CPU neighbour searches use a KD-tree instead of dense scores.
KDTREE_MAX_DIMS = 3


def knn(points: torch.Tensor, k: int, *, chunk: int = KNN_CHUNK) -> torch.Tensor:
    """Indices of the ``k`` nearest points (the point itself included) within each batch item.

    Low-dimensional points on the CPU go through scipy's KD-tree; otherwise the ranking score
    ``2 q.p - |p|^2`` (the negative squared distance up to the per-query constant ``|q|^2``)
    comes out of one matrix product of ``[2q, -1]`` and ``[p, |p|^2]``, chunk of rows by chunk,
    followed by a top-k.

    Parameters
    ----------
    points : Tensor of shape (B, N, C)
        Coordinates or features; the distance is Euclidean in these C dimensions.
    k : int
        Neighbours per point, at most N.
    chunk : int
        Query rows handled at once: memory is O(B * chunk * N), not O(B * N * N).

    Returns
    -------
    Tensor of shape (B, N, k), int64
    """
    b, n, c = points.shape
    if points.device.type == "cpu" and c <= KDTREE_MAX_DIMS:
        return _knn_kdtree(points, k)
    keys = torch.cat([points, (points * points).sum(-1, keepdim=True)], dim=-1)
    keys = keys.transpose(1, 2).contiguous()  # (B, C + 1, N)
    queries = torch.cat([2.0 * points, points.new_full((b, n, 1), -1.0)], dim=-1)
    return torch.cat(
        [
            torch.bmm(queries[:, start : start + chunk], keys).topk(k, dim=-1).indices
            for start in range(0, n, chunk)
        ],
        dim=1,
    )


def _knn_kdtree(points: torch.Tensor, k: int) -> torch.Tensor:
    """:func:`knn` through one KD-tree per batch item (3-D coordinates on the CPU)."""
    out = np.empty((points.shape[0], points.shape[1], k), dtype=np.int64)
    for i, item in enumerate(points.detach().numpy()):
        _, idx = cKDTree(item).query(item, k=k, workers=-1)
        out[i] = np.asarray(idx).reshape(len(item), k)
    return torch.from_numpy(out)


def gather_neighbours(values: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``values`` of every point's neighbours: (B, N, C) and (B, N, k) -> (B, N, k, C)."""
    b, n, c = values.shape
    base = torch.arange(b, device=values.device).view(b, 1, 1) * n
    flat = torch.index_select(values.reshape(b * n, c), 0, (idx + base).reshape(-1))
    return flat.view(b, n, idx.shape[2], c)


def _folded(seq: nn.Sequential) -> tuple[torch.Tensor, torch.Tensor]:
    """Weight (out, in) and bias (out,) of ``Sequential(conv 1x1, BatchNorm)`` in eval mode."""
    conv, bn = seq[0], seq[1]
    if not isinstance(conv, nn.Conv1d | nn.Conv2d) or not isinstance(bn, _BatchNorm):
        raise TypeError(f"expected (convolution, batch norm), got {seq!r}")
    if bn.running_mean is None or bn.running_var is None:
        raise TypeError(f"{bn!r} keeps no running statistics to fold")
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
    weight = conv.weight.reshape(conv.weight.shape[0], -1) * scale[:, None]
    return weight, bn.bias - bn.running_mean * scale


def _block(c_in: int, c_out: int, bn: nn.Module, dims: int) -> nn.Sequential:
    conv = nn.Conv2d if dims == 2 else nn.Conv1d
    return nn.Sequential(conv(c_in, c_out, 1, bias=False), bn, nn.LeakyReLU(SLOPE))


class DGCNN(nn.Module):
    """DGCNN semantic segmentation network (the S3DIS variant of antao97/dgcnn.pytorch).

    Parameters
    ----------
    num_classes : int
        Output classes (13 for S3DIS).
    k : int
        Neighbours of every EdgeConv graph (20 in the published weights).
    in_channels : int
        Per-point input features (9: block-centred xyz, rgb in 0-1, room-normalised xyz).
    knn_channels : slice
        The input features the first graph is built on (the room-normalised xyz).
    emb_dims : int
        Size of the global feature.

    Shapes
    ------
    features (B, N, in_channels) -> logits (B, N, num_classes); N >= k.
    """

    def __init__(
        self,
        num_classes: int = 13,
        *,
        k: int = 20,
        in_channels: int = 9,
        knn_channels: slice = slice(6, 9),
        emb_dims: int = 1024,
        dropout: float = 0.5,
    ) -> None:
        super().__init__()
        self.num_classes = num_classes
        self.k = k
        self.in_channels = in_channels
        self.knn_channels = knn_channels
        self.emb_dims = emb_dims
        self.bn1 = nn.BatchNorm2d(64)
        self.bn2 = nn.BatchNorm2d(64)
        self.bn3 = nn.BatchNorm2d(64)
        self.bn4 = nn.BatchNorm2d(64)
        self.bn5 = nn.BatchNorm2d(64)
        self.bn6 = nn.BatchNorm1d(emb_dims)
        self.bn7 = nn.BatchNorm1d(512)
        self.bn8 = nn.BatchNorm1d(256)
        self.conv1 = _block(2 * in_channels, 64, self.bn1, 2)
        self.conv2 = _block(64, 64, self.bn2, 2)
        self.conv3 = _block(2 * 64, 64, self.bn3, 2)
        self.conv4 = _block(64, 64, self.bn4, 2)
        self.conv5 = _block(2 * 64, 64, self.bn5, 2)
        self.conv6 = _block(3 * 64, emb_dims, self.bn6, 1)
        self.conv7 = _block(emb_dims + 3 * 64, 512, self.bn7, 1)
        self.conv8 = _block(512, 256, self.bn8, 1)
        self.dp1 = nn.Dropout(dropout)
        self.conv9 = nn.Conv1d(256, num_classes, 1, bias=False)

    def forward(
        self, features: torch.Tensor, *, between: Callable[[], None] | None = None
    ) -> torch.Tensor:
        """Per-point class logits.

        Parameters
        ----------
        features : Tensor of shape (B, N, in_channels)
        between : callable, optional
            Called before every stage of the forward pass (six of them), e.g. a cancellation
            check that raises, so a stop request does not wait for a whole batch.
        """
        if self.training:
            return self._forward_plain(features)
        step = between or (lambda: None)
        step()
        idx = knn(features[..., self.knn_channels], self.k)
        x1 = self._edge_conv_mlp(features, idx, self.conv1, self.conv2)
        step()
        x2 = self._edge_conv_mlp(x1, knn(x1, self.k), self.conv3, self.conv4)
        step()
        x3 = self._edge_conv_max(x2, knn(x2, self.k), self.conv5)
        step()
        local = torch.cat([x1, x2, x3], dim=-1)  # (B, N, 192)
        w6, b6 = _folded(self.conv6)
        pooled = functional.leaky_relu((local @ w6.T).amax(dim=1) + b6, SLOPE)  # (B, emb)
        step()
        w7, b7 = _folded(self.conv7)
        w_global, w_local = w7[:, : self.emb_dims], w7[:, self.emb_dims :]
        x = local @ w_local.T + (pooled @ w_global.T + b7)[:, None, :]
        x = functional.leaky_relu(x, SLOPE)
        w8, b8 = _folded(self.conv8)
        x = functional.leaky_relu(x @ w8.T + b8, SLOPE)
        step()
        return x @ self.conv9.weight.reshape(self.num_classes, -1).T

    @staticmethod
    def _edge_weights(first: nn.Sequential) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per-neighbour and per-centre weights of an EdgeConv's first convolution, BN folded."""
        w, b = _folded(first)
        c = w.shape[1] // 2
        return w[:, :c], w[:, c:] - w[:, :c], b

    def _edge_conv_mlp(
        self, x: torch.Tensor, idx: torch.Tensor, first: nn.Sequential, second: nn.Sequential
    ) -> torch.Tensor:
        """EdgeConv with two convolutions, max over neighbours: (B, N, C) -> (B, N, 64)."""
        w_nb, w_centre, b = self._edge_weights(first)
        edges = gather_neighbours(x @ w_nb.T, idx)  # a fresh tensor: safe to change in place
        edges += (x @ w_centre.T + b)[:, :, None, :]
        functional.leaky_relu(edges, SLOPE, inplace=True)
        w2, b2 = _folded(second)
        # max before the (monotone) activation: one LeakyReLU per point, not per edge
        return functional.leaky_relu((edges @ w2.T).amax(dim=2) + b2, SLOPE)

    def _edge_conv_max(
        self, x: torch.Tensor, idx: torch.Tensor, conv: nn.Sequential
    ) -> torch.Tensor:
        """EdgeConv with one convolution: the max over neighbours is taken on the per-point
        neighbour term, so no edge tensor larger than the gathered one is formed."""
        w_nb, w_centre, b = self._edge_weights(conv)
        best = gather_neighbours(x @ w_nb.T, idx).amax(dim=2)
        return functional.leaky_relu(best + x @ w_centre.T + b, SLOPE)

    def _forward_plain(self, features: torch.Tensor) -> torch.Tensor:
        """The textbook formulation (edge tensors through every convolution): used for
        training, and by the tests as the reference the fast path must match."""
        x = features.transpose(1, 2)  # (B, C, N)
        n = x.shape[2]
        e = self._graph_features(x, knn(features[..., self.knn_channels], self.k))
        x1 = self.conv2(self.conv1(e)).amax(dim=-1)
        e = self._graph_features(x1, knn(x1.transpose(1, 2), self.k))
        x2 = self.conv4(self.conv3(e)).amax(dim=-1)
        e = self._graph_features(x2, knn(x2.transpose(1, 2), self.k))
        x3 = self.conv5(e).amax(dim=-1)
        local = torch.cat([x1, x2, x3], dim=1)
        pooled = self.conv6(local).amax(dim=-1, keepdim=True).expand(-1, -1, n)
        x = self.conv8(self.conv7(torch.cat([pooled, local], dim=1)))
        return self.conv9(self.dp1(x)).transpose(1, 2)

    @staticmethod
    def _graph_features(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        """Edge features ``[x_j - x_i, x_i]``: (B, C, N) -> (B, 2C, N, k)."""
        points = x.transpose(1, 2)
        nb = gather_neighbours(points, idx)
        centre = points[:, :, None, :].expand_as(nb)
        return torch.cat([nb - centre, centre], dim=-1).permute(0, 3, 1, 2)

    def extra_repr(self) -> str:
        return (
            f"classes={self.num_classes}, k={self.k}, in_channels={self.in_channels}, "
            f"knn_channels={self.knn_channels.start}:{self.knn_channels.stop}, "
            f"emb_dims={self.emb_dims}"
        )
