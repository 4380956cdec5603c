"""Which of the network's doors and columns are believable (issue 43): each has its size."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX
from jointseg.fusion.fixtures import implausible_columns, implausible_doors

DOOR, WALL, COLUMN = CLASS_INDEX["door"], CLASS_INDEX["wall"], CLASS_INDEX["column"]


def panel(
    rng: np.random.Generator, x0: float, width: float, height: float, bottom: float = 0.0
) -> np.ndarray:
    """A vertical panel in the plane y = 0 from x0 and ``bottom`` up, 2 cm spacing, a little
    noise."""
    n = int(width * height / 0.02**2)
    pts = np.column_stack(
        [rng.uniform(x0, x0 + width, n), np.zeros(n), rng.uniform(bottom, bottom + height, n)]
    )
    return pts + rng.normal(0, 0.004, pts.shape)


@pytest.mark.parametrize(
    ("width", "height", "believable"),
    [
        (0.9, 2.05, True),  # a door leaf
        (2.1, 2.2, True),  # a double door with its frame
        (0.8, 1.2, True),  # the lower part of a leaf, as a sweep sees it
        (0.6, 0.7, False),  # lower than any door seen even in part: a cabinet, a wall
        (3.0, 2.1, False),  # a stretch of wall the network called door
        (1.9, 0.9, False),  # wide and low: a wall below a window, not a door
    ],
)
def test_a_door_of_a_doors_size_is_believed(width: float, height: float, believable: bool) -> None:
    rng = np.random.default_rng(0)
    door = panel(rng, 0.0, width, height)
    wall = panel(rng, width + 0.5, 3.0, 2.6)  # a wall labelled wall beside it is never flagged
    xyz = np.vstack([door, wall])
    labels = np.r_[np.full(len(door), DOOR), np.full(len(wall), WALL)]
    flagged = implausible_doors(xyz, labels)
    assert not flagged[len(door) :].any()
    assert flagged[: len(door)].all() == (not believable)
    assert flagged[: len(door)].any() == (not believable)  # the whole door, or none of it


def test_two_doors_apart_are_judged_each_on_its_own() -> None:
    rng = np.random.default_rng(1)
    leaf = panel(rng, 0.0, 0.9, 2.0)
    stretch = panel(rng, 4.0, 3.2, 2.0)  # 3 m on, a wide "door"
    flagged = implausible_doors(np.vstack([leaf, stretch]), np.full(len(leaf) + len(stretch), DOOR))
    assert not flagged[: len(leaf)].any() and flagged[len(leaf) :].all()


def test_few_or_no_door_points_flag_nothing() -> None:
    xyz = np.random.default_rng(2).uniform(0, 3, (50, 3))
    assert not implausible_doors(xyz, np.full(50, DOOR)).any()
    assert not implausible_doors(xyz, np.full(50, WALL)).any()


def test_a_door_floating_above_the_floor_is_a_wall_the_network_mistook() -> None:
    rng = np.random.default_rng(3)
    standing = panel(rng, 0.0, 0.9, 2.0, bottom=0.05)
    floating = panel(rng, 3.0, 0.9, 1.3, bottom=0.9)  # a wall seen above a desk
    xyz = np.vstack([standing, floating])
    labels = np.full(len(xyz), DOOR)
    # without a floor level, only the size counts: both are door-sized
    assert not implausible_doors(xyz, labels).any()
    flagged = implausible_doors(xyz, labels, floor_z=0.0)
    assert not flagged[: len(standing)].any() and flagged[len(standing) :].all()
    # a floor 1 m lower than the scan's bottom leaves no door standing on it
    assert implausible_doors(xyz, labels, floor_z=-1.0).all()


@pytest.mark.parametrize(("width", "believable"), [(0.5, True), (1.0, True), (1.8, False)])
def test_a_column_wider_than_any_column_is_a_wall_the_network_mistook(
    width: float, believable: bool
) -> None:
    rng = np.random.default_rng(4)
    column = panel(rng, 0.0, width, 2.6)
    door = panel(rng, 3.0, 3.0, 2.1)  # a door of any size is not judged as a column
    xyz = np.vstack([column, door])
    labels = np.r_[np.full(len(column), COLUMN), np.full(len(door), DOOR)]
    flagged = implausible_columns(xyz, labels)
    assert not flagged[len(column) :].any()
    assert flagged[: len(column)].all() == (not believable)
    assert flagged[: len(column)].any() == (not believable)
