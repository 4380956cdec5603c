"""The reference's S3DIS block convention (columns, samples, 9 features) and the room frame."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.network.dgcnn.blocks import block_features, column_blocks, sample_columns
from jointseg.network.dgcnn.room_frame import DEFAULT_ROOM_HEIGHT, room_frame, scan_frame
from jointseg.synth import make_room


def brute_force_columns(xy: np.ndarray, size: float, stride: float) -> list[set[int]]:
    """The reference's loop: corners i * stride, closed squares, as written in room2blocks
    (with a 1e-9 m tolerance: in floats 9 * 0.3 + 1 < 3.7, and a border point would be lost)."""
    limit = xy.max(axis=0)
    nx = max(1, int(np.ceil((limit[0] - size) / stride)) + 1)
    ny = max(1, int(np.ceil((limit[1] - size) / stride)) + 1)
    out = []
    for i in range(nx):
        for j in range(ny):
            x0, y0 = i * stride, j * stride
            inside = (xy[:, 0] >= x0 - 1e-9) & (xy[:, 0] <= x0 + size + 1e-9)
            inside &= (xy[:, 1] >= y0 - 1e-9) & (xy[:, 1] <= y0 + size + 1e-9)
            if inside.any():
                out.append(set(np.flatnonzero(inside).tolist()))
    return out


@pytest.mark.parametrize("stride", [1.0, 0.5, 0.3])
def test_columns_match_the_reference_and_cover_every_point(stride: float) -> None:
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, [3.7, 2.2], size=(2000, 2))
    xy[:5] = [[0, 0], [1.0, 1.0], [0.5, 2.0], [3.7, 0.0], [2.0, 1.5]]  # on borders
    columns = column_blocks(xy, size=1.0, stride=stride, min_points=1)
    bounds = zip(columns.start[:-1], columns.start[1:], strict=True)
    got = [set(columns.points[a:b].tolist()) for a, b in bounds]
    want = brute_force_columns(xy, 1.0, stride)
    assert sorted(map(sorted, got)) == sorted(map(sorted, want))
    assert np.array_equal(np.unique(columns.points), np.arange(len(xy)))
    # a point's weight is one over the number of columns holding it
    owned = np.bincount(columns.points, weights=columns.weight, minlength=len(xy))
    np.testing.assert_allclose(owned, 1.0)


def test_small_columns_are_dropped_unless_all_are_small() -> None:
    rng = np.random.default_rng(1)
    xy = np.concatenate([rng.uniform(0, 1, (500, 2)), rng.uniform([1.2, 0], [1.9, 1], (20, 2))])
    columns = column_blocks(xy, size=1.0, stride=1.0, min_points=100)
    assert columns.sizes.tolist() == [500]
    tiny = column_blocks(xy[500:] - xy[500:].min(axis=0), min_points=100)
    assert tiny.sizes.sum() == 20


@pytest.mark.parametrize("coverage", [None, 1.0, 0.3])
def test_samples_are_disjoint_slices_and_full_coverage_sees_every_point(coverage) -> None:
    rng = np.random.default_rng(2)
    xy = np.concatenate([rng.uniform(0, 2, (9000, 2)), rng.uniform([2.5, 0], [3, 1], (300, 2))])
    columns = column_blocks(xy, size=1.0, stride=0.5)
    samples, column = sample_columns(columns, 1024, coverage=coverage, rng=rng)
    assert samples.shape[1] == 1024 and len(samples) == len(column)
    for c in np.unique(column):
        members = set(columns.points[columns.start[c] : columns.start[c + 1]].tolist())
        drawn = samples[column == c].reshape(-1)
        assert set(drawn.tolist()) <= members
        if len(members) >= 1024:  # disjoint draws, then a top-up from the first points
            assert len(set(drawn.tolist())) == min(len(members), len(drawn))
    owned = np.bincount(np.repeat(np.arange(len(columns)), columns.sizes), weights=columns.weight)
    if coverage is None:
        assert set(samples.reshape(-1).tolist()) == set(range(len(xy)))
        assert len(samples) == np.ceil(columns.sizes / 1024).sum()
    else:
        wanted = np.floor(coverage * owned / 1024 + 0.5)
        expected = np.clip(wanted, 1, np.ceil(columns.sizes / 1024))
        assert len(samples) == expected.sum()


def test_block_features_follow_the_reference() -> None:
    xyz = np.array([[[2.2, 3.1, 0.0], [2.8, 3.9, 1.5], [2.4, 3.5, 3.0]]])
    rgb = np.array([[[1.0, 0.5, 0.0]] * 3])
    feats = block_features(xyz, rgb, np.array([4.0, 5.0, 3.0]))
    assert feats.shape == (1, 3, 9) and feats.dtype == np.float32
    # x, y centred on the sample's minimum plus half a block; z as is
    np.testing.assert_allclose(feats[0, :, 0], [-0.5, 0.1, -0.3], atol=1e-6)
    np.testing.assert_allclose(feats[0, :, 1], [-0.5, 0.3, -0.1], atol=1e-6)
    np.testing.assert_allclose(feats[0, :, 2], [0.0, 1.5, 3.0])
    np.testing.assert_allclose(feats[0, :, 3:6], rgb[0])
    np.testing.assert_allclose(feats[0, :, 6:], xyz[0] / [4.0, 5.0, 3.0], atol=1e-6)


def test_room_frame_finds_floor_and_ceiling_of_a_whole_room() -> None:
    scan = make_room(3, points=60_000)
    frame = room_frame(scan.xyz)
    assert frame.floor and frame.ceiling
    reference = scan_frame(scan.xyz)
    # a whole room: close to the reference's bounding box (the layers' centres, not extremes)
    np.testing.assert_allclose(frame.extent, reference.extent, atol=0.1)
    np.testing.assert_allclose(frame.origin, reference.origin, atol=0.05)


def test_room_frame_of_a_slice_assumes_a_room_height() -> None:
    scan = make_room(3, points=60_000)
    low = scan.xyz[scan.xyz[:, 2] < scan.xyz[:, 2].min() + 1.0]
    frame = room_frame(low)
    assert frame.floor and not frame.ceiling
    assert frame.extent[2] == DEFAULT_ROOM_HEIGHT
    assert scan_frame(low).extent[2] < 1.01  # what the reference would divide by
    assert room_frame(low, height=2.6).extent[2] == 2.6
