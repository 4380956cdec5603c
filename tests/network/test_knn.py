"""The torch neighbour search (used on GPUs) against scipy's KD-tree, on the CPU."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from jointseg.network.randlanet.crops import build_batch
from jointseg.network.randlanet.knn import knn, layer_indices
from jointseg.network.randlanet.model import RandLANetConfig


def _same_up_to_ties(d_ref, i_ref, d, i, points, queries) -> None:
    """Equal distances everywhere; where indices differ, the two points are equally far."""
    np.testing.assert_allclose(d, d_ref, rtol=1e-6, atol=1e-9)
    differ = i != i_ref
    if differ.any():
        q = np.broadcast_to(queries[:, None, :], i.shape + (3,))[differ]
        a = ((points[i[differ]] - q) ** 2).sum(-1)
        b = ((points[i_ref[differ]] - q) ** 2).sum(-1)
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("k", [1, 16])
def test_knn_gives_the_kd_trees_neighbours(k: int) -> None:
    rng = np.random.default_rng(k)
    points = rng.uniform(0, 3, (2, 3000, 3)).astype(np.float32)
    # a grid with many exact ties in distance
    points[1, :1000] = np.round(points[1, :1000] * 10) / 10
    queries = np.concatenate([points[:, :500], rng.uniform(0, 3, (2, 300, 3))], axis=1).astype(
        np.float32
    )
    d, i = knn(torch.from_numpy(points), torch.from_numpy(queries), k, block=128)
    assert d.shape == i.shape == (2, 800, k)
    for b in range(2):
        d_ref, i_ref = cKDTree(points[b]).query(queries[b], k=k)
        d_ref, i_ref = d_ref.reshape(800, k), i_ref.reshape(800, k)
        _same_up_to_ties(
            d_ref**2, i_ref, d[b].numpy(), i[b].numpy(), points[b], queries[b].astype(np.float64)
        )


def test_knn_refuses_bad_shapes() -> None:
    with pytest.raises(ValueError, match="k=5"):
        knn(torch.zeros(1, 4, 3), torch.zeros(1, 2, 3), 5)
    with pytest.raises(ValueError, match="B, N, 3"):
        knn(torch.zeros(4, 3), torch.zeros(2, 3), 1)


def test_layer_indices_match_the_cpu_batch() -> None:
    """The device construction gives the neighbour lists the workers' KD-trees give."""
    rng = np.random.default_rng(3)
    config = RandLANetConfig(num_points=2048)
    xyz = rng.uniform(0, 2, (2, 2048, 3)).astype(np.float32)
    rgb = rng.uniform(0, 1, (2, 2048, 3)).astype(np.float32)
    cpu = build_batch([(xyz[b], rgb[b], None, np.arange(2048)) for b in range(2)], config)
    centred = cpu.features[:, :, :3].contiguous()
    coords, neighbours, pools, ups = layer_indices(centred, config)
    for layer in range(len(config.ratios)):
        assert torch.allclose(coords[layer], cpu.coords[layer])
        assert pools[layer].shape == cpu.pools[layer].shape
        for b in range(2):
            pts = cpu.coords[layer][b].numpy().astype(np.float64)
            ref, got = cpu.neighbours[layer][b].numpy(), neighbours[layer][b].numpy()
            d_ref = ((pts[ref] - pts[:, None]) ** 2).sum(-1)
            d_got = ((pts[got] - pts[:, None]) ** 2).sum(-1)
            _same_up_to_ties(d_ref, ref, d_got, got, pts, pts)
            sub = pts[: cpu.pools[layer].shape[1]]
            up_ref, up_got = cpu.upsamples[layer][b].numpy(), ups[layer][b].numpy()
            d_up_ref = ((sub[up_ref[:, 0]] - pts) ** 2).sum(-1)
            d_up_got = ((sub[up_got[:, 0]] - pts) ** 2).sum(-1)
            np.testing.assert_allclose(d_up_got, d_up_ref, rtol=1e-6, atol=1e-9)
