"""Tests of the synthetic scan generator (jointseg.synth)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from jointseg.classes import CLASS_INDEX, NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.scan import Scan
from jointseg.synth import make_floor, make_room

N = 60_000
CEILING, FLOOR, WALL = CLASS_INDEX["ceiling"], CLASS_INDEX["floor"], CLASS_INDEX["wall"]
DOOR = CLASS_INDEX["door"]


@pytest.fixture(scope="module")
def box_rooms() -> dict[int, Scan]:
    return {seed: make_room(seed, points=N, yaw=0) for seed in range(5)}


@pytest.fixture(scope="module")
def floor_scan() -> Scan:
    return make_floor(3, rooms=4, points=150_000, yaw=0)


def test_deterministic_for_a_seed() -> None:
    a = make_room(11, points=20_000, shape="L")
    b = make_room(11, points=20_000, shape="L")
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_array_equal(a.fields["instance"], b.fields["instance"])


def test_different_seeds_give_different_rooms(box_rooms: dict[int, Scan]) -> None:
    a, b = box_rooms[0], box_rooms[1]
    assert not np.array_equal(a.xyz, b.xyz)
    extent_a = np.ptp(a.xyz, axis=0)
    extent_b = np.ptp(b.xyz, axis=0)
    assert not np.allclose(extent_a, extent_b, atol=0.05)


@pytest.mark.parametrize("points", [1_000, 54_321])
def test_exact_point_count(points: int) -> None:
    scan = make_room(5, points=points, shape="L", scanners=3)
    assert len(scan) == points
    assert scan.rgb is not None and scan.rgb.shape == (points, 3)
    assert scan.fields["instance"].shape == (points,)


def test_labels_colours_and_fields(box_rooms: dict[int, Scan]) -> None:
    for scan in box_rooms.values():
        assert scan.labels is not None and scan.rgb is not None
        assert scan.labels.min() >= 0 and scan.labels.max() < NUM_CLASSES
        assert scan.rgb.dtype == np.uint8
        assert scan.rgb.astype(float).std(axis=0).min() > 10
        inst = scan.fields["instance"]
        assert inst.dtype == np.int32 and inst.min() > 0
        # one object, one class
        pairs = np.unique(np.stack([inst, scan.labels], 1), axis=0)
        assert len(np.unique(pairs[:, 0])) == len(pairs)


def test_most_classes_in_each_room_and_all_across_seeds(box_rooms: dict[int, Scan]) -> None:
    seen: set[int] = set()
    for seed, scan in box_rooms.items():
        present = set(np.unique(scan.labels).tolist())
        assert len(present) >= 11, (seed, sorted(present))
        seen |= present
    assert seen == set(range(NUM_CLASSES))


def test_several_instances_of_furniture(box_rooms: dict[int, Scan]) -> None:
    for scan in box_rooms.values():
        inst = scan.fields["instance"]
        chairs = np.unique(inst[scan.labels == CLASS_INDEX["chair"]])
        clutter = np.unique(inst[scan.labels == CLASS_INDEX["clutter"]])
        walls = np.unique(inst[scan.labels == WALL])
        assert len(chairs) >= 1
        assert len(clutter) >= 5
        assert len(walls) >= 4


def _inner_box(scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    """Room interior (x, y) from the planes of the big wall instances of an axis-aligned room."""
    planes: list[list[float]] = [[], []]
    inst = scan.fields["instance"]
    walls = scan.labels == WALL
    for i in np.unique(inst[walls]):
        xy = scan.xyz[walls & (inst == i), :2]
        if len(xy) < 200:
            continue
        axis = int(np.argmin(xy.std(axis=0)))
        if xy[:, axis].std() < 0.02:
            planes[axis].append(float(np.median(xy[:, axis])))
    lo = np.array([min(planes[0]), min(planes[1])])
    hi = np.array([max(planes[0]), max(planes[1])])
    return lo, hi


def test_points_lie_within_the_room(box_rooms: dict[int, Scan]) -> None:
    for scan in box_rooms.values():
        lo, hi = _inner_box(scan)
        assert np.all(hi - lo > 2.9)
        xy = scan.xyz[:, :2]
        # Walls are seen up to their thickness outside (door and window reveals), no further.
        assert np.all(xy > lo - 0.35) and np.all(xy < hi + 0.35)
        furniture = xy[scan.labels >= CLASS_INDEX["table"]]
        assert np.all(furniture > lo - 0.03) and np.all(furniture < hi + 0.03)
        ceiling_z = scan.xyz[scan.labels == CEILING, 2]
        floor_z = scan.xyz[scan.labels == FLOOR, 2]
        assert abs(np.median(floor_z)) < 0.01
        assert 2.4 < np.median(ceiling_z) < 4.1
        assert scan.xyz[:, 2].min() > -0.05 and scan.xyz[:, 2].max() < ceiling_z.max() + 0.05


def test_l_room_footprint_is_not_convex() -> None:
    for seed in (1, 2):
        scan = make_room(seed, points=N, shape="L", yaw=0)
        xy = scan.xyz[scan.labels == CEILING, :2]
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        size = hi - lo
        counts = []
        for cx in (0, 1):
            for cy in (0, 1):
                x0 = lo[0] + cx * 0.75 * size[0]
                y0 = lo[1] + cy * 0.75 * size[1]
                inside = (xy[:, 0] > x0) & (xy[:, 0] < x0 + 0.25 * size[0])
                inside &= (xy[:, 1] > y0) & (xy[:, 1] < y0 + 0.25 * size[1])
                counts.append(int(inside.sum()))
        counts.sort()
        assert counts[0] == 0, counts  # the removed corner has no ceiling
        assert counts[1] > 20, counts  # ... and both arms are there


def test_box_room_has_four_full_corners(box_rooms: dict[int, Scan]) -> None:
    xy = box_rooms[0].xyz[box_rooms[0].labels == CEILING, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    for cx in (lo[0], hi[0] - 1.0):
        for cy in (lo[1], hi[1] - 1.0):
            inside = (xy[:, 0] > cx) & (xy[:, 0] < cx + 1) & (xy[:, 1] > cy) & (xy[:, 1] < cy + 1)
            assert inside.sum() > 5


def _dominant_angle(xy: np.ndarray) -> float:
    """Rotation in [0, 90) degrees that, undone, minimises the axis-aligned bounding box."""
    best, best_area = 0.0, math.inf
    for deg in np.arange(0.0, 90.0, 0.5):
        a = math.radians(deg)
        r = xy @ np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
        area = float(np.prod(np.ptp(r, axis=0)))
        if area < best_area:
            best, best_area = deg, area
    return best


def test_yaw_rotates_the_room() -> None:
    a = make_room(4, points=30_000, yaw=0)
    b = make_room(4, points=30_000, yaw=30)
    wa, wb = a.xyz[a.labels == WALL, :2], b.xyz[b.labels == WALL, :2]
    assert _dominant_angle(wa) in (0.0, 89.5)
    assert abs(_dominant_angle(wb) - 30.0) <= 1.0
    # same room, only rotated about a vertical axis
    ca, cb = a.xyz - a.xyz.mean(axis=0), b.xyz - b.xyz.mean(axis=0)
    t = math.radians(30)
    rot = np.array([[math.cos(t), -math.sin(t), 0], [math.sin(t), math.cos(t), 0], [0, 0, 1]])
    np.testing.assert_allclose(ca @ rot.T, cb, atol=1e-6)
    np.testing.assert_array_equal(a.labels, b.labels)


def test_density_falls_with_range() -> None:
    scan = make_room(6, points=N, scanners=1)
    rng_ = scan.fields["range"]
    assert np.all(scan.fields["scanner"] == 0)
    near = rng_ < np.percentile(rng_, 25)
    far = rng_ > np.percentile(rng_, 75)
    tree = cKDTree(scan.xyz)
    d, _ = tree.query(scan.xyz, k=2)
    spacing = d[:, 1]
    assert spacing[far].mean() > 1.5 * spacing[near].mean()


def test_range_noise_is_small(box_rooms: dict[int, Scan]) -> None:
    scan = box_rooms[2]
    z = scan.xyz[scan.labels == FLOOR, 2]
    assert 0.0005 < z.std() < 0.01


def test_make_floor_has_several_rooms(floor_scan: Scan) -> None:
    scan = floor_scan
    assert len(scan) == 150_000
    inst = scan.fields["instance"]
    doors = np.unique(inst[scan.labels == DOOR])
    floors = np.unique(inst[scan.labels == FLOOR])
    assert len(doors) >= 4
    assert len(floors) == 5  # four rooms and the corridor, each scanned
    extent = np.ptp(scan.xyz[:, :2], axis=0)
    assert extent.max() > 9.0 and extent.min() > 5.5
    assert set(np.unique(scan.labels).tolist()) >= {0, 1, 2, 5, 6, 7, 8, 10, 12}


def test_progress_is_reported() -> None:
    calls: list[tuple[str, float]] = []
    make_room(0, points=5_000, progress=lambda stage, f: calls.append((stage, f)))
    fractions = [f for _, f in calls]
    assert calls and all(0.0 <= f <= 1.0 for f in fractions)
    assert fractions == sorted(fractions) and fractions[-1] == 1.0


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"points": 999}, "points"),
        ({"points": 50_000_001}, "points"),
        ({"points": 1.5e4}, "points"),
        ({"shape": "round"}, "shape"),
        ({"yaw": float("nan")}, "yaw"),
        ({"scanners": 0}, "scanners"),
    ],
)
def test_make_room_rejects_bad_arguments(kwargs: dict, name: str) -> None:
    with pytest.raises(ConfigError, match=name):
        make_room(0, **kwargs)


def test_bad_seed_and_rooms() -> None:
    with pytest.raises(ConfigError, match="seed"):
        make_room(-1)
    with pytest.raises(ConfigError, match="rooms"):
        make_floor(0, rooms=0)
    with pytest.raises(ConfigError, match="points"):
        make_floor(0, points=10)


def test_furniture_of_different_classes_is_physically_separated(box_rooms: dict[int, Scan]) -> None:
    furniture = [CLASS_INDEX[c] for c in ("table", "chair", "sofa", "bookcase")]
    for seed, scan in box_rooms.items():
        keep = np.isin(scan.labels, furniture)
        xyz, lab = scan.xyz[keep], scan.labels[keep]
        pairs = cKDTree(xyz).query_pairs(0.03, output_type="ndarray")
        mixed = lab[pairs[:, 0]] != lab[pairs[:, 1]]
        assert not mixed.any(), (seed, np.unique(np.sort(lab[pairs[mixed]], axis=1), axis=0))
