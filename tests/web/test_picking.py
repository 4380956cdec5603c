"""Picking and measuring (web.picking): the first surface under a ray, areas, the floor."""

from __future__ import annotations

import numpy as np

from web.picking import floor_height, pick, polygon_area


def test_a_ray_picks_the_point_it_passes_through_on_the_first_surface() -> None:
    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(-2, 2, (4000, 2)), np.zeros(4000)]
    table = np.c_[rng.uniform(-0.5, 0.5, (800, 2)), np.full(800, 0.75)]
    xyz = np.vstack([floor, table])
    target = len(floor) + 10
    origin = xyz[target] + np.array([0.0, -1.0, 3.0])
    hit = pick(xyz, origin, xyz[target] - origin, tolerance=0.02)
    assert hit == target
    # the same ray without the table lands on the floor, not on nothing
    beyond = pick(floor, origin, xyz[target] - origin, tolerance=0.05)
    assert beyond is not None and floor[beyond, 2] == 0.0
    # a ray into empty space hits nothing, and nothing behind the camera counts
    assert pick(xyz, np.array([0.0, 0.0, 5.0]), np.array([0.0, 0.0, 1.0]), 0.05) is None
    assert pick(xyz[:0], origin, np.ones(3), 0.1) is None


def test_polygon_area_of_a_tilted_rectangle_and_of_too_few_corners() -> None:
    corners = np.array([[0, 0, 0], [2, 0, 0], [2, 3, 0], [0, 3, 0]], dtype=float)
    c, s = np.cos(0.7), np.sin(0.7)
    turn = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    assert abs(polygon_area(corners @ turn.T) - 6.0) < 1e-9
    assert polygon_area(corners[:2]) == 0.0


def test_the_floor_is_the_median_of_floor_points_or_a_low_quantile() -> None:
    z = np.r_[np.full(100, 0.2), np.linspace(0.5, 3, 100)]
    labels = np.r_[np.ones(100, int), np.full(100, 2)]
    assert floor_height(z, labels) == 0.2
    assert floor_height(z, np.full(200, 2)) <= 0.21
