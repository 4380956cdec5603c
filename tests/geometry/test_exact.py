"""The geometry's faster kernels against the plain versions they replaced, to the bit.

Each reference below is the earlier implementation, kept here as the specification: the
rewrites (CSR matrices built directly, columns gathered with ``np.take``, sorts instead of
hash tables, voxel counts before renumbering) must give the same arrays, not close ones, since
a threshold compared against a value one ulp away can move a point to another segment.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from jointseg.geometry import alignment, clustering, planes
from jointseg.geometry.segmentation import colour_noise
from jointseg.voxels import cell_means, voxel_index


def _reference_graph(
    tree: cKDTree, xyz: np.ndarray, *, k: int, radius: float
) -> clustering.NeighbourGraph:
    dist, idx = tree.query(xyz, k=k + 1, distance_upper_bound=radius, workers=-1)
    n = len(xyz)
    src = np.repeat(np.arange(n, dtype=np.int64), k + 1).reshape(n, k + 1)
    valid = (idx < n) & (idx != src)
    positive = np.where(valid & (dist > 0), dist, np.inf)
    local = positive.min(axis=1)
    local[~np.isfinite(local)] = radius
    return clustering.NeighbourGraph(n, src[valid], idx[valid].astype(np.int64), dist[valid], local)


def _reference_components(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    graph = coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(n, n)).tocsr()
    return connected_components(graph, directed=False)[1].astype(np.int64)


def _reference_smooth(
    graph: clustering.NeighbourGraph, rgb: np.ndarray, edges: np.ndarray
) -> np.ndarray:
    src, dst = graph.src[edges], graph.dst[edges]
    weights = np.ones(len(src), dtype=np.float32)
    adjacency = coo_matrix((weights, (src, dst)), shape=(graph.n, graph.n)).tocsr()
    colour = rgb.astype(np.float32)
    total = adjacency @ colour + colour
    count = np.asarray(adjacency.sum(axis=1)).ravel() + 1.0
    return total / count[:, None]


def _reference_region_grow(
    graph: clustering.NeighbourGraph,
    rgb: np.ndarray,
    groups: np.ndarray,
    *,
    distance: float,
    point_threshold: float,
    region_threshold: float,
    adaptive: float,
) -> np.ndarray:
    same = (groups[graph.src] == groups[graph.dst]) & graph.within(distance, adaptive=adaptive)
    src, dst = graph.src[same], graph.dst[same]
    colour = rgb.astype(np.float32)
    close = np.linalg.norm(colour[src] - colour[dst], axis=1) < point_threshold
    regions = _reference_components(graph.n, src[close], dst[close])
    count = int(regions.max()) + 1
    means = cell_means(colour, regions, count)
    a, b = regions[src], regions[dst]
    cross = a != b
    keys = np.unique(a[cross] * count + b[cross])
    if len(keys) == 0:
        return regions
    pa, pb = keys // count, keys % count
    similar = np.linalg.norm(means[pa] - means[pb], axis=1) < region_threshold
    return _reference_components(count, pa[similar], pb[similar])[regions]


def _reference_merge_small(
    graph: clustering.NeighbourGraph,
    xyz: np.ndarray,
    regions: np.ndarray,
    groups: np.ndarray,
    weights: np.ndarray | None,
    *,
    min_points: int,
    rounds: int = 4,
) -> np.ndarray:
    regions = np.unique(regions, return_inverse=True)[1]
    for _ in range(rounds):
        sizes = np.bincount(regions, weights=weights)
        small = sizes < min_points
        if not small.any():
            break
        a, b = regions[graph.src], regions[graph.dst]
        cand = small[a] & (a != b)
        if not cand.any():
            break
        count = len(sizes)
        same_group = groups[graph.src[cand]] == groups[graph.dst[cand]]
        keys = (a[cand] * count + b[cand]) * 2 + same_group
        pair_keys, pair_counts = np.unique(keys, return_counts=True)
        same, pair_keys = pair_keys % 2, pair_keys // 2
        pa, pb = pair_keys // count, pair_keys % count
        score = pair_counts + (same.astype(np.int64) << 40) + np.where(small[pb], 0, 1 << 30)
        order = np.lexsort((-score, pa))
        first = np.ones(len(order), dtype=bool)
        first[1:] = pa[order][1:] != pa[order][:-1]
        merged = _reference_components(count, pa[order][first], pb[order][first])
        regions = np.unique(merged[regions], return_inverse=True)[1]
    sizes = np.bincount(regions, weights=weights)
    small_pts = sizes[regions] < min_points
    if small_pts.any() and (~small_pts).any():
        big_idx = np.flatnonzero(~small_pts)
        k = min(8, len(big_idx))
        _, nearest = cKDTree(xyz[big_idx]).query(xyz[small_pts], k=k, workers=-1)
        nearest = big_idx[np.asarray(nearest).reshape(-1, k)]
        same_g = groups[nearest] == groups[small_pts][:, None]
        pick = np.where(same_g.any(axis=1), same_g.argmax(axis=1), 0)
        regions = regions.copy()
        regions[small_pts] = regions[nearest[np.arange(len(pick)), pick]]
        regions = np.unique(regions, return_inverse=True)[1]
    return regions


def _reference_point_normals(xyz: np.ndarray, spacing: float, *, max_voxels: int) -> np.ndarray:
    voxel = max(2.0 * spacing, 1e-3)
    inverse, centroids = voxel_index(xyz, voxel)
    while len(centroids) > max_voxels:
        voxel *= 1.5
        inverse, centroids = voxel_index(xyz, voxel)
    if len(centroids) < 4:
        return np.tile([0.0, 0.0, 1.0], (len(xyz), 1))
    normals = alignment.estimate_normals(centroids, k=min(16, len(centroids) - 1))
    return normals[inverse]


def _reference_ransac(
    points: np.ndarray,
    *,
    iterations: int,
    threshold: float,
    sample: int,
    rng: np.random.Generator,
    axis: np.ndarray | None = None,
    max_tilt_deg: float = 90.0,
) -> tuple[np.ndarray, float, np.ndarray] | None:
    m = len(points)
    if m < 3:
        return None
    triples = rng.integers(0, m, size=(iterations, 3))
    p0, p1, p2 = points[triples[:, 0]], points[triples[:, 1]], points[triples[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-12
    normals = normals[ok] / length[ok, None]
    p0 = p0[ok]
    if axis is not None:
        keep = np.abs(normals @ axis) >= np.cos(np.radians(max_tilt_deg))
        normals, p0 = normals[keep], p0[keep]
    if len(normals) == 0:
        return None
    offsets = -np.einsum("ij,ij->i", normals, p0)
    subset = points[rng.choice(m, size=min(sample, m), replace=False)]
    scores = (np.abs(subset @ normals.T + offsets) < threshold).sum(axis=0)
    best = int(np.argmax(scores))
    normal, offset = normals[best], offsets[best]
    for _ in range(2):
        inliers = np.abs(points @ normal + offset) < threshold
        if inliers.sum() < 3:
            break
        normal, offset = planes.fit_plane(points[inliers])
    inliers = np.abs(points @ normal + offset) < threshold
    return normal, float(offset), inliers


@pytest.fixture(params=[7, clustering.EDGE_CHUNK], ids=["small_chunks", "default_chunks"])
def edge_chunk(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> int:
    """Per-edge arithmetic in chunks of 7 edges too, so every chunk boundary is crossed."""
    monkeypatch.setattr(clustering, "EDGE_CHUNK", request.param)
    return int(request.param)


def _cloud(seed: int, n: int = 3000, *, duplicates: int = 200) -> np.ndarray:
    """Clumps of points with exact duplicates and a few far strays: zero distances, missing
    neighbours beyond the radius and rows of every length."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 2, (12, 3))
    xyz = centres[rng.integers(0, 12, n)] + rng.normal(0, 0.03, (n, 3))
    xyz[:duplicates] = xyz[rng.integers(duplicates, n, duplicates)]
    xyz[-20:] = rng.uniform(5, 9, (20, 3))
    return xyz


def _assert_same_graph(got: clustering.NeighbourGraph, want: clustering.NeighbourGraph) -> None:
    assert got.n == want.n
    for name in ("src", "dst", "dist", "local"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype, name
        np.testing.assert_array_equal(a, b, err_msg=name)


@pytest.mark.parametrize(("seed", "k", "radius"), [(0, 6, 0.05), (1, 3, 0.02), (2, 8, 10.0)])
def test_neighbour_graph_matches_the_reference(
    seed: int, k: int, radius: float, edge_chunk: int
) -> None:
    xyz = _cloud(seed)
    tree = cKDTree(xyz)
    got = clustering.neighbour_graph(tree, xyz, k=k, radius=radius)
    _assert_same_graph(got, _reference_graph(tree, xyz, k=k, radius=radius))
    assert np.all(got.src[1:] >= got.src[:-1])  # sorted by src, which components relies on


@pytest.mark.parametrize("seed", range(4))
def test_components_match_the_coo_version_sorted_or_not(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    m = int(rng.integers(0, 2 * n))
    src, dst = rng.integers(0, n, m), rng.integers(0, n, m)
    want = _reference_components(n, src, dst)
    order = np.argsort(src, kind="stable")
    for s, d in ((src, dst), (src[order], dst[order]), (np.r_[src, src], np.r_[dst, dst])):
        got = clustering.components(n, s, d)
        assert got.dtype == np.int64
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8, np.int64])
@pytest.mark.parametrize("m", [0, 1, 2, 7, 1000, 50_000])
def test_colour_distance_is_the_norm_to_the_bit(dtype: type, m: int, edge_chunk: int) -> None:
    rng = np.random.default_rng(m)
    colour: np.ndarray = (rng.random((300, 3)) * 255).astype(dtype)
    a, b = rng.integers(0, 300, m), rng.integers(0, 300, m)
    want = np.linalg.norm(colour[a] - colour[b], axis=1)  # uint8 wraps before the norm, too
    got = clustering.colour_distance(colour, a, b)
    assert got.dtype == want.dtype
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(clustering.colour_close(colour, a, b, 90.0), want < 90.0)
    four = rng.random((300, 4))
    np.testing.assert_array_equal(
        clustering.colour_distance(four, a, b), np.linalg.norm(four[a] - four[b], axis=1)
    )


@pytest.mark.parametrize("seed", range(3))
def test_smooth_colours_and_colour_noise_match_the_reference(seed: int, edge_chunk: int) -> None:
    xyz = _cloud(seed)
    graph = clustering.neighbour_graph(cKDTree(xyz), xyz, k=6, radius=0.08)
    # voxel mean colours are not integers: their float32 sums depend on the order of the terms
    rgb = (np.random.default_rng(seed).random((len(xyz), 3)) * 255).astype(np.float32)
    edges = graph.within(0.03, adaptive=2.5)
    scale = np.maximum(graph.local[graph.src], graph.local[graph.dst])
    np.testing.assert_array_equal(edges, graph.dist < np.maximum(0.03, 2.5 * scale))
    got = clustering.smooth_colours(graph, rgb, edges)
    want = _reference_smooth(graph, rgb, edges)
    assert got.dtype == want.dtype == np.float32
    np.testing.assert_array_equal(got, want)
    order = np.random.default_rng(seed).permutation(len(graph.src))  # a graph built otherwise
    shuffled = clustering.NeighbourGraph(
        graph.n, graph.src[order], graph.dst[order], graph.dist[order], graph.local
    )
    np.testing.assert_array_equal(clustering.smooth_colours(shuffled, rgb, edges[order]), want)
    nearest = np.flatnonzero(np.r_[True, graph.src[1:] != graph.src[:-1]])
    a, b = graph.src[nearest], graph.dst[nearest]
    want_noise = float(np.median(np.linalg.norm(got[a] - got[b], axis=1)))
    assert colour_noise(graph, got) == want_noise


@pytest.mark.parametrize("seed", range(4))
def test_region_growing_and_merging_match_the_reference(seed: int, edge_chunk: int) -> None:
    rng = np.random.default_rng(seed)
    xyz = _cloud(seed, n=4000)
    graph = clustering.neighbour_graph(cKDTree(xyz), xyz, k=6, radius=0.1)
    # patchy colours: a few flat colours with noise, so regions form, touch and merge
    rgb = (rng.integers(0, 4, len(xyz))[:, None] * 60 + rng.normal(0, 6, (len(xyz), 3))).clip(
        0, 255
    )
    groups = (xyz[:, 0] > 1.0).astype(np.int64) + 2 * (xyz[:, 2] > 1.0)
    kwargs: dict[str, Any] = {"distance": 0.03, "point_threshold": 14.0, "region_threshold": 20.0}
    got = clustering.region_grow_rgb(graph, rgb, groups, adaptive=2.5, **kwargs)
    graph_ref = clustering.neighbour_graph(cKDTree(xyz), xyz, k=6, radius=0.1)
    want = _reference_region_grow(graph_ref, rgb, groups, adaptive=2.5, **kwargs)
    np.testing.assert_array_equal(got, want)
    assert len(np.unique(want)) > 5  # the case is not trivial
    weights = rng.integers(1, 4, len(xyz)).astype(np.float64)
    for w in (None, weights):
        want_merged = _reference_merge_small(graph, xyz, want, groups, w, min_points=40)
        for tree in (None, cKDTree(xyz)):
            merged = clustering.merge_small_regions(
                graph, xyz, got, groups, w, min_points=40, tree=tree
            )
            np.testing.assert_array_equal(merged, want_merged)


@pytest.mark.parametrize("seed", range(3))
def test_nearest_among_the_others_is_their_own_trees_answer(seed: int) -> None:
    rng = np.random.default_rng(seed)
    xyz = _cloud(seed, n=2000, duplicates=0)
    excluded = rng.random(len(xyz)) < [0.01, 0.3, 0.9][seed]
    others = np.flatnonzero(~excluded)
    for k in (1, 8):
        got = clustering.nearest_among(cKDTree(xyz), xyz, excluded, k)
        _, want = cKDTree(xyz[others]).query(xyz[excluded], k=k)
        assert got is not None
        np.testing.assert_array_equal(got, others[np.asarray(want).reshape(-1, k)])
    # equally distant neighbours: two trees may order them differently, so no answer
    grid = np.stack(np.meshgrid(*[np.arange(6.0)] * 3), axis=-1).reshape(-1, 3)
    middle = np.zeros(len(grid), dtype=bool)
    middle[len(grid) // 2] = True
    assert clustering.nearest_among(cKDTree(grid), grid, middle, 8) is None
    few = np.zeros(len(xyz), dtype=bool)
    few[5:] = True  # five others for k + 1 = 9 asked
    assert clustering.nearest_among(cKDTree(xyz), xyz, few, 8) is None


@pytest.mark.parametrize("max_voxels", [50, 400, 100_000])
def test_point_normals_match_the_voxel_loop(max_voxels: int) -> None:
    xyz = _cloud(5, n=5000)
    got = alignment.point_normals(xyz, 0.005, max_voxels=max_voxels)
    want = _reference_point_normals(xyz, 0.005, max_voxels=max_voxels)
    np.testing.assert_array_equal(got, want)
    few = xyz[:3]
    np.testing.assert_array_equal(
        alignment.point_normals(few, 0.005), _reference_point_normals(few, 0.005, max_voxels=10)
    )


def test_robust_bounds_are_the_two_quantiles() -> None:
    xyz = _cloud(7, n=20_001)
    lo, hi = planes.robust_bounds(xyz)
    np.testing.assert_array_equal(lo, np.quantile(xyz, 0.001, axis=0))
    np.testing.assert_array_equal(hi, np.quantile(xyz, 0.999, axis=0))
    lo, hi = planes.robust_bounds(xyz, 0.2)
    np.testing.assert_array_equal(lo, np.quantile(xyz, 0.2, axis=0))
    np.testing.assert_array_equal(hi, np.quantile(xyz, 0.8, axis=0))


@pytest.mark.parametrize("seed", range(3))
def test_ransac_matches_the_reference(seed: int) -> None:
    rng = np.random.default_rng(seed)
    floor = np.column_stack([rng.uniform(0, 3, (6000, 2)), rng.normal(0, 0.004, 6000)])
    clutter = rng.uniform(0, 3, (3000, 3))
    pts = np.vstack([floor, clutter])
    kwargs: dict[str, Any] = {"iterations": 400, "threshold": 0.01, "sample": 1500}
    for axis in (None, np.array([0.0, 0.0, 1.0])):
        got = planes.ransac_plane(pts, rng=np.random.default_rng(seed), axis=axis, **kwargs)
        want = _reference_ransac(pts, rng=np.random.default_rng(seed), axis=axis, **kwargs)
        assert got is not None and want is not None
        np.testing.assert_array_equal(got[0], want[0])
        assert got[1] == want[1]
        np.testing.assert_array_equal(got[2], want[2])


def test_box_faces_with_known_bounds_are_the_same() -> None:
    rng = np.random.default_rng(3)
    box = rng.uniform(0, 1, (9000, 3)) * [4.0, 3.0, 2.5]
    for axis in range(3):  # the six faces, densely sampled
        face = rng.uniform(0, 1, (3000, 3)) * [4.0, 3.0, 2.5]
        face[:1500, axis] = 0.0
        face[1500:, axis] = [4.0, 3.0, 2.5][axis]
        box = np.vstack([box, face])
    kwargs: dict[str, Any] = {
        "face_distance": 0.08,
        "plane_distance": 0.015,
        "iterations": 200,
        "sample": 1000,
        "max_tilt_deg": 15.0,
        "min_points": 200,
    }
    plain = planes.box_face_planes(box, rng=np.random.default_rng(0), **kwargs)
    known = planes.box_face_planes(
        box, rng=np.random.default_rng(0), bounds=planes.robust_bounds(box), **kwargs
    )
    assert len(plain) == len(known) == 6
    for (p, idx), (q, jdx) in zip(plain, known, strict=True):
        np.testing.assert_array_equal(p.normal, q.normal)
        assert p.offset == q.offset
        np.testing.assert_array_equal(idx, jdx)
