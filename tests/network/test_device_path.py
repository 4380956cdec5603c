"""RandLA-Net's device path (torch sub-sample, plan, crops, searches, projection), run on the CPU
against the numpy/scipy path it must agree with."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from jointseg.network.anchored import (
    anchored_cloud,
    cell_ids,
    crop_members,
    crops_inside,
    plan_crops,
)
from jointseg.network.device_crops import device_crop_members, device_plan_crops
from jointseg.network.device_grid import device_anchored_cloud
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig
from jointseg.network.randlanet.predict import RandLANetPredictor
from jointseg.scan import Scan
from jointseg.synth import make_room

GRID = 0.04


def _cloud_points(seed: int, n: int, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Clustered points (many per cell, some cells alone) far from the origin, and colours."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(0, 3, (n, 3)) + offset
    xyz[: n // 4] = np.round(xyz[: n // 4] / GRID) * GRID  # on cell edges
    rgb = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    return xyz, rgb


@pytest.mark.parametrize("colour", [True, False])
@pytest.mark.parametrize("chunks", [1, 3])
@pytest.mark.parametrize("offset", [0.0, 4321.5])
def test_device_cloud_is_the_anchored_cloud_bit_for_bit(
    colour: bool, chunks: int, offset: float
) -> None:
    xyz, rgb = _cloud_points(0, 20_000, offset)
    lower = xyz.min(axis=0) - 0.013
    blocks = [
        (x, r if colour else None)
        for x, r in zip(*map(np.array_split, (xyz, rgb), [chunks] * 2), strict=True)
    ]
    ref = anchored_cloud(blocks, GRID, lower)
    dev = device_anchored_cloud(blocks, GRID, lower, "cpu")
    np.testing.assert_array_equal(dev.ids.numpy(), ref.ids)
    assert dev.xyz.dtype == torch.float32 and dev.rgb.dtype == torch.float32
    assert dev.xyz.numpy().tobytes() == ref.xyz.tobytes()
    assert dev.rgb.numpy().tobytes() == ref.rgb.tobytes()
    if chunks > 1:  # chunked sums are the whole scan's
        whole = device_anchored_cloud([(xyz, rgb if colour else None)], GRID, lower, "cpu")
        assert whole.xyz.numpy().tobytes() == dev.xyz.numpy().tobytes()


def _squared(query: np.ndarray, centroids: np.ndarray, idx: np.ndarray) -> np.ndarray:
    diff = query.astype(np.float64) - centroids[idx].astype(np.float64)
    return (diff**2).sum(axis=1)


@pytest.mark.slow
def test_device_nearest_is_the_kd_trees() -> None:
    xyz, rgb = _cloud_points(1, 10_000, 100.0)
    # leave holes: every point of some cells removed, so neighbours are cells away
    keep = np.floor(xyz[:, 0] / 0.3).astype(int) % 3 != 1
    lower = xyz.min(axis=0)
    ref = anchored_cloud([(xyz[keep], rgb[keep])], GRID, lower)
    dev = device_anchored_cloud([(xyz[keep], rgb[keep])], GRID, lower, "cpu")
    rng = np.random.default_rng(2)
    queries = np.concatenate(
        [
            xyz,  # the holes included
            rng.uniform(-1, 4, (3000, 3)) + 100.0,  # outside the cloud's box too
            lower + np.round(rng.uniform(0, 3, (2000, 3)) / GRID) * GRID,  # on cell corners
            lower + rng.uniform(0, 3, (500, 3)) * [1, 1, 0] + [0, 0, 50],  # far above
        ]
    )
    got = dev.nearest(queries).numpy()
    want = ref.nearest(queries)
    query32 = (queries - lower).astype(np.float32)
    np.testing.assert_allclose(
        _squared(query32, ref.xyz, got), _squared(query32, ref.xyz, want), rtol=1e-12
    )
    assert (got == want).mean() > 0.99  # ties only


@pytest.mark.parametrize(("points", "num_points"), [(500, 2048), (6000, 2048), (20_000, 1024)])
def test_device_plan_and_members_are_the_cpus(points: int, num_points: int) -> None:
    xyz, rgb = _cloud_points(points, points, 7.0)
    cloud = anchored_cloud([(xyz, rgb)], GRID, xyz.min(axis=0))
    ref = plan_crops(cloud, num_points, 0.5, seed=5)
    dev = device_plan_crops(torch.from_numpy(cloud.xyz), num_points, 0.5, seed=5)
    assert len(dev) == len(ref) and dev.crop_size == ref.crop_size
    np.testing.assert_array_equal(dev.centres, ref.centres)
    np.testing.assert_allclose(dev.radius, ref.radius, rtol=1e-6)
    for crop in range(min(len(ref), 5)):
        want = crop_members(cloud, ref, crop, seed=5)
        got = device_crop_members(torch.from_numpy(cloud.xyz), ref, crop, seed=5).numpy()
        # the same crop in the same order, up to points equally far from the centre (the
        # points on cell edges make many exact ties)
        centre = ref.centres[crop][None, :]
        np.testing.assert_array_equal(
            _squared(np.repeat(centre, len(got), 0), cloud.xyz, got),
            _squared(np.repeat(centre, len(want), 0), cloud.xyz, want),
        )
        assert (got == want).mean() > 0.99


@pytest.fixture(scope="module")
def predictors() -> tuple[RandLANetPredictor, RandLANetPredictor]:
    """A small random RandLA-Net run by both paths (the device path forced on the CPU)."""
    torch.manual_seed(0)
    model = RandLANet(RandLANetConfig(num_points=2048, d_out=(8, 16, 32, 64, 128)))
    cpu = RandLANetPredictor(model, device="cpu", batch_size=2)
    dev = RandLANetPredictor(model, device="cpu", batch_size=2, device_path=True)
    assert not cpu.on_device and dev.on_device
    return cpu, dev


@pytest.fixture(scope="module")
def room() -> Scan:
    return make_room(4, points=15_000)


@pytest.mark.slow
def test_device_path_predicts_as_the_cpu_path(predictors, room) -> None:
    cpu, dev = predictors
    want = cpu.predict(room, seed=1)
    got = dev.predict(room, seed=1)
    assert got.crops == want.crops > 1
    assert set(got.timings) == set(want.timings) == {"subsample", "crops", "project"}
    assert got.labels.dtype == np.int32 and got.probs.dtype == np.float32
    assert (got.labels == want.labels).mean() >= 0.995
    # float32 sums in other orders (crop centring, softmax sums) and an occasional tie in a
    # neighbour search: differences of about 2e-5 at most were seen
    np.testing.assert_allclose(got.probs, want.probs, atol=1e-4)


@pytest.mark.slow
def test_device_path_cells_are_the_cpu_paths(predictors, room) -> None:
    cpu, dev = predictors
    lower = room.xyz.min(axis=0)
    plan = cpu.plan(anchored_cloud([(room.xyz, room.rgb)], cpu.grid_size, lower), seed=2)
    dev_plan = dev.plan(anchored_cloud([(room.xyz, room.rgb)], dev.grid_size, lower), seed=2)
    np.testing.assert_array_equal(dev_plan.centres, plan.centres)
    middle = float(np.median(room.xyz[:, 0]))
    tile = room.subset(np.flatnonzero(room.xyz[:, 0] < middle + 1.0))
    crops = np.flatnonzero(
        crops_inside(plan, lower, np.full(2, -np.inf), np.array([middle, np.inf]))
    )
    assert len(crops) >= 1
    want = cpu.predict_cells(tile, plan, lower, crops, seed=2)
    got = dev.predict_cells(tile, plan, lower, crops, seed=2)
    np.testing.assert_array_equal(got.ids, want.ids)
    np.testing.assert_array_equal(got.seen, want.seen)
    np.testing.assert_allclose(got.sums, want.sums, atol=1e-4)
    np.testing.assert_array_equal(got.point_cell, want.point_cell)


def test_own_cell_is_the_point_s_own_grid_cell_and_the_nearest_outside_the_cloud() -> None:
    xyz, rgb = _cloud_points(3, 20_000, 250.0)
    lower = xyz.min(axis=0) - 0.013
    cloud = anchored_cloud([(xyz, rgb)], GRID, lower)
    rows = cloud.own_cell(xyz)
    # each point's row is the cell holding it, and a cell's centroid lies in it
    np.testing.assert_array_equal(cloud.ids[rows], cell_ids(xyz, GRID, lower))
    centroid_cells = np.floor((cloud.xyz[rows].astype(np.float64)) / GRID)
    assert np.mean(np.all(centroid_cells == np.floor((xyz - lower) / GRID), axis=1)) > 0.99
    # a point of a cell the cloud lacks takes its nearest sub-sampled point
    strangers = np.array([[-5.0, -5.0, -5.0], [10.0, 10.0, 10.0]]) + 250.0
    np.testing.assert_array_equal(cloud.own_cell(strangers), cloud.nearest(strangers))
    assert np.array_equal(cloud.rows(xyz, "cell"), rows)
    assert np.array_equal(cloud.rows(xyz, "nearest"), cloud.nearest(xyz))
    # most points' own cell is their nearest centroid's, not all (that is the difference)
    assert 0.5 < np.mean(rows == cloud.nearest(xyz)) < 1.0
    # the device twin gives the same rows
    dev = device_anchored_cloud([(xyz, rgb)], GRID, lower, "cpu")
    queries = np.concatenate([xyz, strangers])
    np.testing.assert_array_equal(dev.rows(queries, "cell").numpy(), cloud.own_cell(queries))


@pytest.mark.parametrize("spread", [3.0, 2.0e5])
def test_distinct_cells_are_np_unique_of_the_packed_ids(spread: float) -> None:
    """The dense renumbering (a small box) and the fallback (cells across 83 km, a box too big
    to number densely) both give np.unique's ids and inverse."""
    from jointseg.network.anchored import AXIS_BITS, _distinct_cells, _pack

    rng = np.random.default_rng(7)
    xyz = rng.uniform(0, spread, (30_000, 3))
    xyz[:100] = xyz[100:200]  # shared cells
    cells = np.floor(xyz / GRID).astype(np.int64)
    np.clip(cells, 0, (1 << AXIS_BITS) - 1, out=cells)
    want_ids, want_inverse = np.unique(_pack(cells), return_inverse=True)
    ids, inverse = _distinct_cells(cells)
    np.testing.assert_array_equal(ids, want_ids)
    np.testing.assert_array_equal(np.asarray(inverse).reshape(-1), want_inverse.reshape(-1))
