"""Segment purity and segment counts on synthetic rooms and floors (issue targets: purity
>= 0.97 on every scan, a sane number of segments, every wall/floor/ceiling a main plane)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX
from jointseg.geometry import GeometryResult, segment
from jointseg.metrics import segment_purity
from jointseg.scan import Scan
from jointseg.synth import make_floor, make_room

ROOM_POINTS = 200_000
FLOOR_POINTS = 600_000
ROOMS = [(seed, shape) for seed in range(10) for shape in ("box", "L")]
FLOORS = [0, 1]
STRUCTURE = [CLASS_INDEX["ceiling"], CLASS_INDEX["floor"], CLASS_INDEX["wall"]]


@cache
def room(seed: int, shape: str) -> tuple[Scan, GeometryResult]:
    scan = make_room(seed, points=ROOM_POINTS, shape=shape)  # random yaw from the seed
    return scan, segment(scan)


@cache
def floor(seed: int) -> tuple[Scan, GeometryResult]:
    scan = make_floor(seed, points=FLOOR_POINTS)
    return scan, segment(scan)


def structural_coverage(scan: Scan, result: GeometryResult) -> float:
    assert scan.labels is not None
    structural = np.isin(scan.labels, STRUCTURE)
    return float(result.main_plane[structural].mean())


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "shape"), ROOMS)
def test_room_purity_and_segment_count(seed: int, shape: str) -> None:
    scan, result = room(seed, shape)
    assert result.segments.shape == (len(scan),)
    assert segment_purity(scan.labels, result.segments) >= 0.97
    # a sane count: more than the main planes, far fewer than thousands of crumbs
    assert len(result.planes) < result.n_segments <= 1000


@pytest.mark.slow
@pytest.mark.parametrize("seed", FLOORS)
def test_floor_purity_and_segment_count(seed: int) -> None:
    scan, result = floor(seed)
    assert segment_purity(scan.labels, result.segments) >= 0.97
    assert len(result.planes) < result.n_segments <= 3000


def test_median_segment_count_is_a_few_hundred() -> None:
    counts = [room(seed, shape)[1].n_segments for seed, shape in ROOMS]
    assert 50 <= float(np.median(counts)) <= 600


@pytest.mark.parametrize(("seed", "shape"), [(1, "L"), (3, "L"), (0, "box")])
def test_walls_floors_and_ceilings_are_main_planes_in_rooms(seed: int, shape: str) -> None:
    scan, result = room(seed, shape)
    assert structural_coverage(scan, result) >= 0.9


@pytest.mark.slow
@pytest.mark.parametrize("seed", FLOORS)
def test_walls_floors_and_ceilings_are_main_planes_on_whole_floors(seed: int) -> None:
    scan, result = floor(seed)
    assert structural_coverage(scan, result) >= 0.9
    # beyond the six box faces: the interior walls of the floor
    assert sum(p.kind == "wall" for p in result.planes) >= 4


def test_l_room_gets_walls_beyond_the_box_faces() -> None:
    scan, result = room(1, "L")
    assert {p.kind for p in result.planes} >= {"box_face", "wall"}
    assert scan.labels is not None
    walls = scan.labels == CLASS_INDEX["wall"]
    further = np.isin(result.plane_id, [i for i, p in enumerate(result.planes) if p.kind == "wall"])
    assert (walls & further).sum() > 0.05 * walls.sum()


@pytest.mark.slow
@pytest.mark.parametrize("yaw", [17.0, 45.0, 73.0])
def test_any_yaw_gives_the_same_segmentation(yaw: float) -> None:
    base = make_room(0, points=150_000, yaw=0.0)
    turned = make_room(0, points=150_000, yaw=yaw)  # the same room rotated
    r0, r1 = segment(base), segment(turned)
    p0 = segment_purity(base.labels, r0.segments)
    p1 = segment_purity(turned.labels, r1.segments)
    assert abs(p0 - p1) <= 0.01
    assert r1.n_segments == pytest.approx(r0.n_segments, rel=0.25)


@pytest.mark.slow
def test_yaw_estimate_follows_the_room() -> None:
    for yaw in (0.0, 12.0, -30.0):
        result = segment(make_room(2, points=100_000, yaw=yaw))
        delta = (result.params.yaw_deg - yaw + 45.0) % 90.0 - 45.0
        assert abs(delta) < 1.0


@pytest.mark.slow
def test_adaptive_thresholds_follow_density() -> None:
    sparse = make_room(4, points=80_000, yaw=0.0)
    dense = make_room(4, points=400_000, yaw=0.0)
    rs, rd = segment(sparse), segment(dense)
    assert rs.params.spacing > 1.5 * rd.params.spacing
    assert rs.params.cluster_distance > rd.params.cluster_distance
    for scan, result in ((sparse, rs), (dense, rd)):
        assert segment_purity(scan.labels, result.segments) >= 0.97
