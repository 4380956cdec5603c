"""The clip box and the slice (web.clipping): what they keep of a job's points."""

from __future__ import annotations

import numpy as np

from jointseg.classes import NUM_CLASSES
from web.clipping import STEP, ClipFrame
from web.scene import SceneData

FLOOR, WALL = 1, 2


def scene(xyz: np.ndarray, fused: np.ndarray) -> SceneData:
    """Scene data of ``xyz`` (already centred), its robust box the bulk's box."""
    n = xyz.shape[0]
    zeros = np.zeros(n, np.int32)
    return SceneData(
        xyz=xyz.astype(np.float32),
        centre=np.zeros(3),
        extent=np.array([4.0, 3.0, 2.6]),
        rgb=np.full((n, 3), 128, np.uint8),
        network=fused,
        fused=fused,
        truth=None,
        segments=zeros,
        changed=np.zeros(n, bool),
        total_points=n,
        voxel=None,
        spacing=0.02,
        counts={"fused": np.zeros(NUM_CLASSES + 1, np.int64)},
        report=None,
    )


def a_room_with_noise_under_its_floor() -> tuple[SceneData, np.ndarray]:
    """A 4 x 3 x 2.6 m room (floor at -1.3, its points 5 mm noisy) with stray points under the
    floor and beyond the walls; the rows of the strays."""
    rng = np.random.default_rng(0)
    floor = np.column_stack(
        [rng.uniform(-2, 2, 2000), rng.uniform(-1.5, 1.5, 2000), rng.normal(-1.3, 0.005, 2000)]
    )
    wall = np.column_stack(
        [np.full(500, -2.0), rng.uniform(-1.5, 1.5, 500), rng.uniform(-1.3, 1.3, 500)]
    )
    strays = np.array([[0.0, 0.0, -1.6], [1.0, 0.5, -2.5], [2.4, 0.0, 0.0], [0.0, -1.9, 1.4]])
    xyz = np.vstack([floor, wall, strays])
    fused = np.concatenate([np.full(2000, FLOOR), np.full(500, WALL), np.zeros(4)]).astype(np.int32)
    return scene(xyz, fused), np.arange(2500, 2504)


def full_box(frame: ClipFrame) -> tuple[float, ...]:
    return tuple(v for axis in range(3) for v in (0.0, float(frame.reach[axis])))


def test_the_clip_box_at_full_range_keeps_every_point_even_under_the_floor() -> None:
    data, strays = a_room_with_noise_under_its_floor()
    frame = ClipFrame.of(data)
    below = data.xyz[:, 2] < frame.floor
    assert below.sum() > 500  # half the floor's own points lie under its median height
    kept = frame.kept(data.xyz, full_box(frame), None)
    assert kept.all(), f"{(~kept).sum()} points hidden, {(~kept[strays]).sum()} of 4 strays"
    corners = np.array([[0.0, 0.0, -2.6], [0.2, 0.2, -2.4]])  # a box under the floor
    assert frame.overlaps(corners, full_box(frame), None)


def test_a_clip_box_moved_off_an_end_cuts_there_and_the_ends_left_alone_stay_open() -> None:
    data, strays = a_room_with_noise_under_its_floor()
    frame = ClipFrame.of(data)
    box = list(full_box(frame))
    box[4] = 0.5  # z from 0.5 m above the floor: the floor and what lies under it go
    kept = frame.kept(data.xyz, tuple(box), None)
    z = data.xyz[:, 2] - frame.floor
    assert not kept[z < 0.5].any() and kept[z >= 0.5].all()
    box = list(full_box(frame))
    box[1] = float(frame.reach[0]) - STEP  # x up to one step short of the end
    kept = frame.kept(data.xyz, tuple(box), None)
    x = data.xyz[:, 0] - frame.corner[0]
    assert not kept[x > box[1]].any() and kept[x <= box[1]].all()
    assert kept[strays[:2]].all()  # under the floor, inside x: still kept


def test_the_slice_keeps_only_its_heights() -> None:
    data, _ = a_room_with_noise_under_its_floor()
    frame = ClipFrame.of(data)
    kept = frame.kept(data.xyz, None, (1.0, 1.5))
    z = data.xyz[:, 2] - frame.floor
    assert np.array_equal(kept, (z >= 1.0) & (z <= 1.5))
