"""Augmentation for other sensors: density, partial rooms and slices, handheld sensors' gaps,
tilt, colour."""

from __future__ import annotations

import numpy as np

from jointseg.network.randlanet.crops import grid_subsample
from jointseg.synth import make_room
from jointseg.training.augment import (
    AugmentParams,
    augment_colour,
    cut_region,
    density_sample,
    sensor_gaps,
    tilt_matrix,
)
from jointseg.training.batches import region_crop
from jointseg.training.sources import BASE_GRID


def test_density_sampling_thins_to_one_point_per_cell() -> None:
    rng = np.random.default_rng(0)
    xyz = rng.uniform(0, 1, (20_000, 3)).astype(np.float32)
    rgb = rng.uniform(0, 1, (20_000, 3)).astype(np.float32)
    labels = (xyz[:, 0] > 0.5).astype(np.int32)
    pts, colour, lab = density_sample(xyz, rgb, labels, 0.1, rng)
    assert 1000 <= len(pts) <= 1331  # 10 x 10 x 10 cells, up to 11 per axis with the offset
    assert colour.shape == pts.shape and lab.shape == (len(pts),)
    # majority labels follow the points: cells well left of x = 0.5 are class 0
    assert (lab[pts[:, 0] < 0.35] == 0).all() and (lab[pts[:, 0] > 0.65] == 1).all()


def test_cuts_make_partial_rooms_and_floor_slices() -> None:
    rng = np.random.default_rng(1)
    xyz = rng.uniform(0, 4, (10_000, 3)).astype(np.float32)
    centre = np.array([2, 2, 1.5], dtype=np.float32)
    plane = cut_region(xyz, centre, rng, AugmentParams(partial=1.0, slice=0.0))
    assert plane is not None and 0.4 < plane.mean() < 0.95
    band = cut_region(xyz, centre, rng, AugmentParams(partial=0.0, slice=1.0))
    assert band is not None and xyz[band, 2].max() <= xyz[:, 2].min() + 1.8
    assert cut_region(xyz, centre, rng, AugmentParams(partial=0.0, slice=0.0)) is None


def test_tilt_is_a_small_rotation() -> None:
    rng = np.random.default_rng(2)
    for _ in range(20):
        m = tilt_matrix(rng, 3.0)
        assert np.allclose(m @ m.T, np.eye(3), atol=1e-6)
        up = m @ np.array([0, 0, 1.0])
        assert np.degrees(np.arccos(np.clip(up[2], -1, 1))) <= 3.0 + 1e-4


def test_colour_drop_and_grey() -> None:
    rng = np.random.default_rng(3)
    rgb = rng.uniform(0, 1, (500, 3)).astype(np.float32)
    assert not augment_colour(rgb, rng, AugmentParams(colour_drop=1.0)).any()
    grey = augment_colour(rgb, rng, AugmentParams(colour_drop=0.0, grey=1.0))
    assert np.allclose(grey[:, 0], grey[:, 1]) and np.allclose(grey[:, 1], grey[:, 2])
    shifted = augment_colour(rgb, rng, AugmentParams(colour_drop=0.0, grey=0.0))
    assert shifted.min() >= 0 and shifted.max() <= 1 and not np.allclose(shifted, rgb)


def test_sparse_crops_cover_more_ground_with_the_same_points() -> None:
    """A crop sampled at 6 cm spans a wider area than one at the network's 4 cm grid, and both
    hold about the points asked for: what a sparse scanner's crop looks like at inference."""
    room = make_room(9, points=200_000)
    cloud = grid_subsample(room.xyz, room.rgb, room.labels, BASE_GRID)
    centre = cloud.xyz[len(cloud.xyz) // 2]
    rng = np.random.default_rng(4)
    spans = {}
    for density, name in ((0.0, "grid"), (1.0, "sparse")):
        aug = AugmentParams(
            density=density, density_range=(0.06, 0.06), partial=0, slice=0, holes=0, no_ceiling=0
        )
        crop = region_crop(cloud, centre, 4096, 0.04, rng, aug)
        assert 0.8 * 4096 <= len(crop.xyz) <= 4096
        spans[name] = np.median(np.linalg.norm(crop.xyz - centre, axis=1))
    assert spans["sparse"] > 1.25 * spans["grid"]  # about 6 / 4 on surfaces


def test_handheld_gaps_drop_the_ceiling_or_punch_holes() -> None:
    rng = np.random.default_rng(5)
    room = make_room(3, points=60_000)
    assert room.labels is not None and (room.labels == 0).any()
    bare = sensor_gaps(
        room.xyz, room.labels, room.xyz[0], rng, AugmentParams(no_ceiling=1.0, holes=0.0)
    )
    assert bare is not None and not (room.labels[bare] == 0).any()
    assert bare.sum() == (room.labels != 0).sum()  # nothing else goes
    holed = sensor_gaps(
        room.xyz, room.labels, room.xyz[0], rng, AugmentParams(no_ceiling=0.0, holes=1.0)
    )
    assert holed is not None and 0.0005 < 1 - holed.mean() < 0.5
    # the dropped points are at most four balls of radius 0.5 m: a greedy cover by balls of
    # radius 1 m (a hole's diameter) around dropped points needs no more than four
    gone, balls = room.xyz[~holed], 0
    while len(gone):
        gone = gone[np.linalg.norm(gone - gone[0], axis=1) > 1.0]
        balls += 1
    assert 1 <= balls <= 4
    assert (
        sensor_gaps(room.xyz, room.labels, room.xyz[0], rng, AugmentParams(no_ceiling=0, holes=0))
        is None
    )


def test_a_colour_cast_moves_the_channels_apart() -> None:
    rng = np.random.default_rng(6)
    rgb = np.full((2000, 3), 0.5, dtype=np.float32)
    plain = AugmentParams(colour_drop=0, grey=0, exposure=0, colour_cast=0)
    cast = plain.model_copy(update={"colour_cast": 1.0, "cast_range": (0.6, 1.4)})
    spread = [
        np.ptp(augment_colour(rgb, rng, p).mean(axis=0)) for p in (plain, cast) for _ in range(20)
    ]
    # white balance alone moves the channels by a few per cent; a cast by tens of per cent
    assert np.median(spread[20:]) > 2 * np.median(spread[:20])
