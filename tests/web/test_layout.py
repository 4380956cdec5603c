"""Panel layout and overview camera: copies side by side with gaps, all in view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.support.camera_math import project
from web.layout import GAP_RATIO, overview_camera, panel_offsets, title_position


def test_panels_sit_side_by_side_with_gaps_centred_on_the_origin() -> None:
    extent = np.array([6.0, 4.0, 3.0])
    offsets = panel_offsets(extent, 3)
    assert np.allclose(offsets[:, 1:], 0)
    assert np.allclose(np.diff(offsets[:, 0]), 6.0 * (1 + GAP_RATIO))
    assert np.isclose(offsets[:, 0].mean(), 0)
    # neighbouring panels never overlap
    right_edge, next_left_edge = offsets[0, 0] + 3.0, offsets[1, 0] - 3.0
    assert next_left_edge - right_edge == pytest.approx(6.0 * GAP_RATIO)
    assert panel_offsets(extent, 1)[0].tolist() == [0, 0, 0]


def test_title_sits_above_the_panel() -> None:
    x, y, z = title_position(np.array([6.0, 4.0, 3.0]))
    assert x == 0 and y == 2.0 and z > 1.5


@pytest.mark.parametrize("count", [1, 3, 5])
@pytest.mark.parametrize("aspect", [0.8, 1.35, 2.2])
def test_overview_camera_sees_every_corner_of_every_panel(count: int, aspect: float) -> None:
    extent = np.array([7.0, 5.0, 2.8])
    pose = overview_camera(extent, count, aspect=aspect)
    position, look_at = np.array(pose.position), np.array(pose.look_at)
    assert position[2] > look_at[2]  # looks down onto the rooms
    half = extent / 2
    reach = 0.0
    for offset in panel_offsets(extent, count):
        for sx in (-1, 1):
            for sy in (-1, 1):
                for sz in (-1, 1):
                    corner = offset + half * [sx, sy, sz]
                    u, v = project(corner, position, look_at, pose.fov, aspect)
                    assert abs(u) < 1 and abs(v) < 1, (corner, u, v)
                    reach = max(reach, abs(u), abs(v))
    assert reach > 0.6  # and the rooms fill the view rather than sit small in its middle


@pytest.mark.parametrize("view", ["Top", "Front", "Side"])
@pytest.mark.parametrize("count", [1, 5])
def test_plan_and_elevations_look_from_their_side_nearly_orthographic_and_see_the_row(
    view: str, count: int
) -> None:
    from web.layout import (
        ORTHO_SCALE_ERROR,
        VIEW_DIRECTIONS,
        ortho_camera,
        row_axis,
    )

    extent, aspect = np.array([7.0, 5.0, 2.8]), 1.6
    pose = ortho_camera(extent, count, view, aspect=aspect)
    position = np.array(pose.position)
    direction = np.asarray(VIEW_DIRECTIONS[view]) / np.linalg.norm(VIEW_DIRECTIONS[view])
    assert np.allclose(position / np.linalg.norm(position), direction)
    if view == "Top":  # a plan looks straight down
        down = -position / np.linalg.norm(position)
        assert math.degrees(math.acos(float(down @ [0.0, 0.0, -1.0]))) < 1.0
    # far enough that the row's depth changes the scale by at most ORTHO_SCALE_ERROR
    offsets = panel_offsets(extent, count, axis=row_axis(view))
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    points = np.concatenate([offset + extent / 2 * corners for offset in offsets])
    depths = (position - points) @ direction
    assert depths.max() / depths.min() - 1.0 <= ORTHO_SCALE_ERROR + 1e-9
    assert pose.near < depths.min() and pose.far > depths.max()
    # every corner of every panel (side by side, none hidden behind another) in the view, and
    # the row fills it
    reach = 0.0
    for point in points:
        u, v = project(point, position, np.zeros(3), pose.fov, aspect)
        assert abs(u) < 1 and abs(v) < 1, (point, u, v)
        reach = max(reach, abs(u), abs(v))
    assert reach > 0.85


def test_the_side_elevation_lays_the_row_out_along_y_with_titles_on_the_far_edge() -> None:
    extent = np.array([6.0, 4.0, 3.0])
    offsets = panel_offsets(extent, 3, axis=1)
    assert np.allclose(offsets[:, [0, 2]], 0)
    assert np.allclose(np.diff(offsets[:, 1]), 4.0 * (1 + GAP_RATIO))
    x, y, z = title_position(extent, axis=1)
    assert x == -3.0 and y == 0 and z > 1.5  # seen from +x, the far edge is at -x
