"""Exact k-nearest neighbours in torch, so the searches run where the network runs.

On a GPU the searches of a crop (five layers of 16 k points or fewer) are a few matrix
products: query blocks against all points, ``topk`` per block. Blocks bound the memory to
``block x N`` distances per crop. On a CPU scipy's KD-tree stays faster, so the training and
inference code use this only on CUDA devices; the same code runs on the CPU for tests, where it
must give exactly scipy's neighbours (ties in distance may come in either order).
"""

from __future__ import annotations

import torch

from jointseg.network.randlanet.model import RandLANetConfig

#: Queries per block: 2 048 x 16 384 float32 distances per crop are 128 MiB.
BLOCK = 2048
#: Query-point pairs held at once over the whole batch (float32, three temporaries: 1.5 GiB),
#: so a batch of many large crops takes smaller blocks instead of tens of GiB.
PAIRS = 1 << 27


def knn(
    points: torch.Tensor, queries: torch.Tensor, k: int, *, block: int = BLOCK
) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` nearest ``points`` of every query, nearest first, per batch item.

    Parameters
    ----------
    points : (B, N, 3) float tensor
    queries : (B, M, 3) float tensor
    k : at most N

    Returns
    -------
    (B, M, k) squared distances (float32) and (B, M, k) int64 indices into ``points``.

    Squared distances are computed as exact differences (not the ``|a|^2 + |b|^2 - 2ab``
    expansion, whose rounding can reorder near neighbours), in float32 like scipy's inputs.
    """
    if points.dim() != 3 or queries.dim() != 3 or points.shape[-1] != 3:
        raise ValueError(f"knn wants (B, N, 3) and (B, M, 3), got {points.shape}, {queries.shape}")
    n = points.shape[1]
    if not 1 <= k <= n:
        raise ValueError(f"k={k} must be between 1 and the {n} points")
    step = max(1, min(block, PAIRS // max(points.shape[0] * n, 1)))
    dists, idx = [], []
    for start in range(0, queries.shape[1], step):
        q = queries[:, start : start + step]
        d2 = _squared_distances(q, points)
        d, i = torch.topk(d2, k, dim=-1, largest=False, sorted=True)
        dists.append(d)
        idx.append(i)
    return torch.cat(dists, dim=1), torch.cat(idx, dim=1)


def _squared_distances(queries: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """(B, b, N) squared distances, summed x, y, z in that order (as scipy), one coordinate at a
    time so no (B, b, N, 3) difference tensor is held."""
    d2 = (queries[..., 0].unsqueeze(2) - points[..., 0].unsqueeze(1)).square_()
    for axis in (1, 2):
        d2 += (queries[..., axis].unsqueeze(2) - points[..., axis].unsqueeze(1)).square_()
    return d2


def layer_indices(
    xyz: torch.Tensor, config: RandLANetConfig
) -> tuple[list[torch.Tensor], list[torch.Tensor], list[torch.Tensor], list[torch.Tensor]]:
    """RandLA-Net's per-layer coordinates, neighbours, pooling and upsampling indices for
    shuffled crops ``xyz`` (B, N, 3), on their device: the first N / ratio points of a layer are
    its random sample (the same construction as
    :func:`jointseg.network.randlanet.crops.build_batch`)."""
    coords, neighbours, pools, ups = [], [], [], []
    current = xyz
    for ratio in config.ratios:
        n = current.shape[1]
        k = min(config.k, n)
        _, nb = knn(current, current, k)
        if k < config.k:
            nb = torch.cat([nb, nb[:, :, :1].expand(-1, -1, config.k - k)], dim=2)
        keep = max(1, n // ratio)
        sub = current[:, :keep]
        _, up = knn(sub, current, 1)
        coords.append(current)
        neighbours.append(nb)
        pools.append(nb[:, :keep])
        ups.append(up)
        current = sub
    return coords, neighbours, pools, ups
