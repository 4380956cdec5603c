"""The structure reading (issue 43): floor, ceiling and walls from geometry alone."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX
from jointseg.geometry import GeometryParams, GeometryResult, segment
from jointseg.geometry.structure import CEILING, FLOOR, WALL, read_structure
from jointseg.scan import Scan
from jointseg.synth import make_room

#: Classes that lie in a wall's plane: reading them as wall is the geometry's honest view (the
#: vote keeps their labels where the network sees them).
IN_WALL = [CLASS_INDEX[c] for c in ("wall", "window", "door", "board", "column")]
FURNITURE = [CLASS_INDEX[c] for c in ("table", "chair", "sofa", "bookcase")]


@functools.cache
def room(seed: int, yaw: float | None = None) -> tuple[Scan, GeometryResult]:
    scan = make_room(seed, points=120_000, shape="box" if seed % 2 == 0 else "L", yaw=yaw)
    return scan, segment(scan, seed=0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_floor_ceiling_and_walls_are_read_where_they_are(seed: int) -> None:
    scan, geo = room(seed)
    assert geo.structure is not None and geo.structure_confidence is not None
    truth, read = scan.labels, geo.structure
    assert truth is not None
    for kind, precision, recall in ((FLOOR, 0.95, 0.85), (CEILING, 0.9, 0.9)):
        assert np.mean(truth[read == kind] == kind) >= precision
        assert np.mean(read[truth == kind] == kind) >= recall
    assert np.mean(np.isin(truth[read == WALL], IN_WALL)) >= 0.9
    assert np.mean(read[truth == WALL] == WALL) >= 0.7
    # table tops, chairs, sofas and bookcases are not structure
    assert np.mean(read[np.isin(truth, FURNITURE)] >= 0) <= 0.05
    assert np.all(geo.structure_confidence[read < 0] == 0)
    sure = geo.structure_confidence[read >= 0]
    assert np.all((sure > 0) & (sure <= 1))
    assert geo.floor_z == pytest.approx(np.percentile(scan.xyz[truth == FLOOR, 2], 50), abs=0.05)


def test_the_reading_does_not_depend_on_the_rooms_yaw() -> None:
    # the segments themselves differ a little with the yaw; the reading follows them
    straight, turned = room(2, 0.0)[1], room(2, 33.0)[1]
    assert straight.structure is not None and turned.structure is not None
    assert np.mean(straight.structure == turned.structure) >= 0.93


def test_a_scan_without_its_ceiling_still_has_floor_and_walls() -> None:
    scan, _ = room(0)
    keep = scan.xyz[:, 2] < np.percentile(scan.xyz[:, 2], 99) - 0.4
    cut = Scan(xyz=scan.xyz[keep], rgb=scan.rgb[keep], labels=scan.labels[keep])
    geo = segment(cut, seed=0)
    assert geo.ceiling_z is None and geo.floor_z is not None
    assert geo.structure is not None and cut.labels is not None
    assert not np.any(geo.structure == CEILING)
    assert np.mean(geo.structure[cut.labels == WALL] == WALL) >= 0.5
    assert np.mean(geo.structure[cut.labels == FLOOR] == FLOOR) >= 0.85


def test_a_desk_seen_alone_is_not_a_storey() -> None:
    rng = np.random.default_rng(0)
    top = np.column_stack(
        [rng.uniform(0, 1.6, 5000), rng.uniform(0, 0.8, 5000), np.full(5000, 0.75)]
    )
    floor = np.column_stack(
        [rng.uniform(-1, 2.6, 5000), rng.uniform(-1, 1.8, 5000), np.zeros(5000)]
    )
    xyz = np.vstack([top, floor]) + rng.normal(0, 0.002, (10_000, 3))
    reading = read_structure(xyz[:5000], np.zeros(5000, np.int64), 0.01)
    assert reading.floor_z is None and not reading.on_surface.any()
    # with the floor below it, the floor is floor and the desk top is not structure
    segments = np.r_[np.zeros(5000, np.int64), np.ones(5000, np.int64)]
    both = read_structure(xyz, segments, 0.01)
    assert both.kind.tolist() == [-1, FLOOR] and both.floor_z == pytest.approx(0.0, abs=0.01)


def test_switched_off_it_reads_nothing() -> None:
    scan, _ = room(1)
    geo = segment(scan, GeometryParams(structure=False), seed=0)
    assert geo.structure is None and "structure" not in geo.timings
    assert "structure" in room(1)[1].timings
