"""Each step of the geometric segmentation on data whose answer is known by construction."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from jointseg.geometry import alignment, clustering, planes


def grid_plane(n: int, *, z: float = 0.0, step: float = 0.02) -> np.ndarray:
    g = np.arange(n) * step
    xx, yy = np.meshgrid(g, g)
    return np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)])


def test_ransac_finds_the_plane_among_outliers() -> None:
    rng = np.random.default_rng(0)
    plane = grid_plane(60, z=1.0)
    plane[:, 2] += rng.normal(0, 0.002, len(plane))
    outliers = rng.uniform([0, 0, 0], [1.2, 1.2, 2.0], size=(1500, 3))
    pts = np.vstack([plane, outliers])
    fit = planes.ransac_plane(
        pts,
        iterations=300,
        threshold=0.01,
        sample=2000,
        rng=rng,
        axis=np.array([0, 0, 1.0]),
        max_tilt_deg=10,
    )
    assert fit is not None
    normal, offset, inliers = fit
    assert abs(abs(normal[2]) - 1) < 1e-3
    assert abs(abs(offset) - 1.0) < 2e-3
    assert inliers[: len(plane)].mean() > 0.99
    assert inliers[len(plane) :].mean() < 0.05


def test_ransac_respects_the_tilt_limit() -> None:
    rng = np.random.default_rng(1)
    wall = grid_plane(40)[:, [2, 0, 1]]  # the plane x = 0
    fit = planes.ransac_plane(
        wall,
        iterations=100,
        threshold=0.01,
        sample=500,
        rng=rng,
        axis=np.array([0, 0, 1.0]),
        max_tilt_deg=15,
    )
    assert fit is None  # a vertical plane is never accepted as a floor


def graph_of(xyz: np.ndarray, k: int = 8, radius: float = 1.0) -> clustering.NeighbourGraph:
    return clustering.neighbour_graph(cKDTree(xyz), xyz, k=k, radius=radius)


def test_euclidean_clusters_follow_pcl_semantics() -> None:
    # a chain of points 4 cm apart is one cluster at d_th = 5 cm even though its ends are 2 m
    # apart; a second chain 10 cm away is another cluster
    chain = np.column_stack([np.arange(50) * 0.04, np.zeros(50), np.zeros(50)])
    other = chain + [0, 0.10, 0]
    xyz = np.vstack([chain, other])
    labels = clustering.euclidean_clusters(graph_of(xyz), np.ones(100, bool), tolerance=0.05)
    assert len(np.unique(labels[:50])) == 1 and len(np.unique(labels[50:])) == 1
    assert labels[0] != labels[50]
    # excluded points (main planes) get -1 and cut the chain in two
    member = np.ones(100, bool)
    member[25] = False
    cut = clustering.euclidean_clusters(graph_of(xyz), member, tolerance=0.05)
    assert cut[25] == -1 and cut[0] != cut[49]


def test_region_growing_splits_by_colour_and_never_crosses_groups() -> None:
    xyz = grid_plane(40)
    rgb = np.zeros((len(xyz), 3))
    rgb[xyz[:, 0] < 0.39] = (200, 40, 40)
    rgb[xyz[:, 0] >= 0.39] = (40, 40, 200)
    graph = graph_of(xyz, radius=0.05)
    one_group = np.zeros(len(xyz), dtype=np.int64)
    regions = clustering.region_grow_rgb(
        graph, rgb, one_group, distance=0.05, point_threshold=20, region_threshold=30
    )
    assert len(np.unique(regions)) == 2
    assert len(np.unique(regions[xyz[:, 0] < 0.39])) == 1
    # two groups of one colour stay two regions
    groups = (xyz[:, 1] > 0.39).astype(np.int64)
    same_colour = np.full((len(xyz), 3), 128.0)
    regions = clustering.region_grow_rgb(
        graph, same_colour, groups, distance=0.05, point_threshold=20, region_threshold=30
    )
    assert len(np.unique(regions)) == 2


def test_region_merging_joins_regions_with_close_mean_colours() -> None:
    xyz = grid_plane(40)
    rgb = np.full((len(xyz), 3), 100.0)
    rgb[xyz[:, 0] >= 0.39] = 125.0  # a sharp step larger than the point threshold
    graph = graph_of(xyz, radius=0.05)
    groups = np.zeros(len(xyz), dtype=np.int64)
    split = clustering.region_grow_rgb(
        graph, rgb, groups, distance=0.05, point_threshold=20, region_threshold=None
    )
    merged = clustering.region_grow_rgb(
        graph, rgb, groups, distance=0.05, point_threshold=20, region_threshold=50
    )
    assert len(np.unique(split)) == 2 and len(np.unique(merged)) == 1


def test_small_regions_merge_into_their_neighbour_and_no_point_is_lost() -> None:
    xyz = grid_plane(30)
    regions = np.zeros(len(xyz), dtype=np.int64)
    regions[:5] = 1  # a 5-point crumb at the edge
    graph = graph_of(xyz, radius=0.05)
    groups = np.zeros(len(xyz), dtype=np.int64)
    out = clustering.merge_small_regions(graph, xyz, regions, groups, min_points=10)
    assert out.shape == regions.shape
    assert len(np.unique(out)) == 1


def test_dominant_yaw_recovers_a_rotation() -> None:
    rng = np.random.default_rng(3)
    angles = rng.choice([0, 90, 180, 270], size=4000) + rng.normal(0, 1.0, 4000) + 23.0
    normals = np.column_stack(
        [np.cos(np.radians(angles)), np.sin(np.radians(angles)), rng.normal(0, 0.05, 4000)]
    )
    assert alignment.dominant_yaw(normals) == pytest.approx(23.0, abs=0.3)
    assert alignment.dominant_yaw(normals @ alignment.rotation_z(-40).T) == pytest.approx(
        -17.0, abs=0.3
    )
