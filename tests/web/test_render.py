"""Screenshots drawn by the viewer (web.render): the nearest point wins a pixel, points are the
size the browser draws them, and the plan's picture is truly orthographic."""

from __future__ import annotations

import numpy as np

from web.render import Cloud, Eye, Label, Lines, Projection, draw_scene

BACK = (10, 20, 30)
RED, BLUE, GREEN = (255, 0, 0), (0, 0, 255), (0, 255, 0)


def looking_down(ortho: bool) -> Eye:
    return Eye(np.array([0.0, -1e-3, 10.0]), np.zeros(3), fov=np.radians(40.0), ortho=ortho)


def test_the_nearest_point_covers_the_one_behind_whatever_the_order() -> None:
    far = Cloud(np.array([[0.0, 0.0, 0.0]]), np.array([RED], np.uint8), 0.2)
    near = Cloud(np.array([[0.0, 0.0, 1.0]]), np.array([BLUE], np.uint8), 0.2)
    for clouds in ([far, near], [near, far]):
        image = draw_scene(looking_down(False), 100, 100, BACK, clouds)
        assert tuple(image[50, 50]) == BLUE
        assert tuple(image[2, 2]) == BACK


def test_a_point_is_as_big_as_the_browser_draws_it() -> None:
    # viser: gl_PointSize = point_size * height / tan(fov / 2) / depth
    eye, point = looking_down(False), Cloud(np.zeros((1, 3)), np.array([RED], np.uint8), 0.1)
    image = draw_scene(eye, 200, 200, BACK, [point])
    side = int((image == RED).all(axis=2).any(axis=0).sum())
    expected = 0.1 * 200 / np.tan(eye.fov / 2) / 10.0
    assert abs(side - expected) <= 1, (side, expected)


def test_the_plan_keeps_one_scale_at_every_height_and_a_perspective_view_does_not() -> None:
    points = np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 3.0]])  # a wall's foot and top, seen above
    columns = {o: Projection(looking_down(o), 400, 400)(points)[0] for o in (True, False)}
    assert abs(columns[True][0] - columns[True][1]) < 1e-9
    assert abs(columns[False][0] - columns[False][1]) > 10


def test_lines_and_titles_are_drawn_over_the_points() -> None:
    grid = np.linspace(-2, 2, 41)
    floor = np.array([[x, y, 0.0] for x in grid for y in grid])
    wall = Cloud(floor, np.full((floor.shape[0], 3), RED, np.uint8), 0.2)
    line = Lines(np.array([[[-1.0, 0.0, 0.1], [1.0, 0.0, 0.1]]]), np.array([[GREEN, GREEN]]), 3.0)
    title = Label("T", np.zeros(3))
    image = draw_scene(looking_down(True), 200, 200, BACK, [wall], [line], [title])
    assert (image == GREEN).all(axis=2).sum() > 50
    assert (image == (255, 255, 255)).all(axis=2).sum() > 20  # the title's white box


def test_a_box_in_one_colour_for_all_its_edges_is_drawn() -> None:
    """A selected object's box is sent with one colour for every edge ((3,), as viser takes
    it); the screenshot drew it with an IndexError (issue 63)."""
    edges = np.array([[[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0]], [[1.0, -1.0, 0.0], [1.0, 1.0, 0.0]]])
    box = Lines(edges, np.array(GREEN, np.uint8), 3.0)
    image = draw_scene(looking_down(True), 200, 200, BACK, [], [box])
    green = (image == GREEN).all(axis=2)
    assert green[:, :100].sum() > 50 and green[:, 100:].sum() > 50  # both edges
