"""DGCNN's device path (blocks built, gathered and summed with torch on the network's device),
run here on the CPU: every torch twin equals its numpy original, and the whole prediction equals
the numpy path's for the same seed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from jointseg.exceptions import Cancelled
from jointseg.network import DGCNNParams
from jointseg.network.dgcnn.blocks import block_features, column_blocks, sample_columns
from jointseg.network.dgcnn.device_blocks import (
    block_features_torch,
    column_blocks_torch,
    sample_columns_torch,
)
from jointseg.network.dgcnn.device_frame import frame_torch
from jointseg.network.dgcnn.device_predict import device_sample_features
from jointseg.network.dgcnn.predict import DGCNNPredictor, load_dgcnn_state
from jointseg.scan import Scan
from jointseg.synth import make_room

CPU = torch.device("cpu")


def room_xy(seed: int, points: int) -> np.ndarray:
    """A synthetic room's horizontal coordinates, shifted to start at 0 (as predict does)."""
    xy = make_room(seed, points=points).xyz[:, :2]
    return xy - xy.min(axis=0)


def border_xy() -> np.ndarray:
    """Points exactly on column borders and corners (shared by 2 to 9 columns at stride 0.5),
    a dense patch, and a sparse corner whose columns fall below min_points."""
    rng = np.random.default_rng(3)
    grid = np.stack(np.meshgrid(np.arange(0, 3.01, 0.5), np.arange(0, 2.01, 0.5)), -1)
    dense = rng.uniform(0.2, 1.8, (3000, 2))
    sparse = rng.uniform(2.6, 3.0, (20, 2))
    return np.concatenate([grid.reshape(-1, 2), dense, sparse, [[0.0, 0.0], [3.0, 2.0]]])


def same_columns(xy: np.ndarray, **kwargs) -> None:
    ref = column_blocks(xy, **kwargs)
    dev = column_blocks_torch(torch.from_numpy(xy), **kwargs)
    np.testing.assert_array_equal(dev.points.numpy(), ref.points)
    np.testing.assert_array_equal(dev.start.numpy(), ref.start)
    np.testing.assert_array_equal(dev.weight.numpy(), ref.weight)
    np.testing.assert_array_equal(dev.sizes.numpy(), ref.sizes)


@pytest.mark.parametrize("stride", [1.0, 0.5, 0.3])
def test_columns_equal_numpy_on_a_room(stride: float) -> None:
    same_columns(room_xy(0, 20_000), size=1.0, stride=stride, min_points=100)


@pytest.mark.parametrize("min_points", [1, 100, 10_000])
def test_columns_equal_numpy_on_borders_and_small_columns(min_points: int) -> None:
    xy = border_xy()
    ref = column_blocks(xy, stride=0.5, min_points=min_points)
    assert (ref.sizes < 100).any() or min_points != 1  # small columns are there to drop
    assert ref.weight.min() < 0.2  # some points are shared by many columns
    same_columns(xy, stride=0.5, min_points=min_points)


def test_columns_of_random_and_empty_input() -> None:
    rng = np.random.default_rng(1)
    same_columns(rng.uniform(0, 7.3, (5000, 2)), size=1.5, stride=0.7, min_points=30)
    same_columns(np.zeros((0, 2)), stride=0.5)
    same_columns(np.zeros((3, 2)), stride=0.5)  # one column, below min_points: kept


@pytest.mark.parametrize("coverage", [None, 1.0, 0.3, 2.5])
@pytest.mark.parametrize("num_points", [64, 512])
def test_samples_equal_numpy_for_the_same_seed(coverage, num_points: int) -> None:
    xy = np.concatenate([room_xy(1, 15_000), border_xy() + 8.0])  # includes small columns
    ref_cols = column_blocks(xy, stride=0.5, min_points=10)
    assert (ref_cols.sizes < num_points).any() and (ref_cols.sizes > num_points).any()
    ref, ref_col = sample_columns(
        ref_cols, num_points, coverage=coverage, rng=np.random.default_rng(7)
    )
    dev_cols = column_blocks_torch(torch.from_numpy(xy), stride=0.5, min_points=10)
    rng = np.random.default_rng(7)
    dev, dev_col = sample_columns_torch(dev_cols, num_points, coverage=coverage, rng=rng)
    np.testing.assert_array_equal(dev.numpy(), ref)
    np.testing.assert_array_equal(dev_col, ref_col)
    # the generator is left where the original leaves it
    sample_columns(ref_cols, num_points, coverage=coverage, rng=(after := np.random.default_rng(7)))
    assert rng.random() == after.random()


def test_features_equal_numpy() -> None:
    rng = np.random.default_rng(2)
    xyz = rng.uniform(0, 4, (3, 128, 3))
    rgb = rng.uniform(0, 1, (3, 128, 3)).astype(np.float32)
    extent = np.array([4.0, 3.5, 2.9])
    shift = rng.uniform(0, 1, (3, 1, 3))
    t = torch.from_numpy
    np.testing.assert_array_equal(
        block_features_torch(t(xyz), t(rgb), t(extent), size=1.5).numpy(),
        block_features(xyz, rgb, extent, size=1.5),
    )
    np.testing.assert_array_equal(
        block_features_torch(t(xyz), t(rgb), t(extent), shift=t(shift)).numpy(),
        block_features(xyz, rgb, extent, shift=shift),
    )


@pytest.mark.parametrize("params", [DGCNNParams(), DGCNNParams(room_size=(6.0, 5.0))])
def test_sample_features_equal_the_predictors(dgcnn_random_weights, params) -> None:
    predictor = on_cpu(dgcnn_random_weights, params)
    scan = make_room(2, points=5_000)
    frame = predictor.frame(scan)
    rng = np.random.default_rng(0)
    xyz = np.stack([rng.uniform(0, 1, (64, 3)), [30.0, 12.0, 0.0] + rng.uniform(0, 1, (64, 3))])
    rgb = rng.uniform(0, 1, xyz.shape).astype(np.float32)
    dev = device_sample_features(torch.from_numpy(xyz), torch.from_numpy(rgb), frame, params)
    np.testing.assert_array_equal(dev.numpy(), predictor.sample_features(xyz, rgb, frame))


def on_cpu(weights, params: DGCNNParams, device_path: bool | None = None) -> DGCNNPredictor:
    model, card = load_dgcnn_state(weights)
    return DGCNNPredictor(
        model, card, device="cpu", batch_size=3, params=params, device_path=device_path
    )


@pytest.mark.parametrize(
    "params",
    [DGCNNParams(), DGCNNParams(room_height=2.7), DGCNNParams(frame="scan")],
)
def test_room_frame_equals_numpy(dgcnn_random_weights, params) -> None:
    """Whole room (floor and ceiling found), a 1 m slice (no ceiling: assumed height), noise
    below the floor, and the other frame options."""
    predictor = on_cpu(dgcnn_random_weights, params)
    room = make_room(4, points=20_000)
    rng = np.random.default_rng(0)
    noisy = np.concatenate([room.xyz, rng.uniform(0, 1, (30, 3)) - [0, 0, 0.2]])
    for xyz in (room.xyz, room.xyz[room.xyz[:, 2] < 1.0], noisy):
        ref = predictor.frame(Scan(xyz))
        dev = frame_torch(torch.from_numpy(xyz), params)
        np.testing.assert_array_equal(dev.origin, ref.origin)
        np.testing.assert_array_equal(dev.extent, ref.extent)
        assert (dev.floor, dev.ceiling) == (ref.floor, ref.ceiling)


def predictors(weights, params: DGCNNParams) -> tuple[DGCNNPredictor, DGCNNPredictor]:
    """The numpy path and the device path forced on the CPU, same weights."""
    cpu, dev = on_cpu(weights, params), on_cpu(weights, params, device_path=True)
    assert not cpu.on_device and dev.on_device
    return cpu, dev


@pytest.mark.slow
@pytest.mark.parametrize(
    "params",
    [
        DGCNNParams(num_points=64),  # overlapping columns
        DGCNNParams(num_points=128, stride=1.0),
        DGCNNParams(num_points=64, stride=1.0, coverage=0.2),  # most points projected
        DGCNNParams(num_points=64, stride=1.0, coverage=None, frame="scan", min_block_points=150),
        DGCNNParams(num_points=64, stride=1.0, room_size=(4.0, 4.0)),
    ],
)
def test_device_path_equals_the_numpy_path(dgcnn_random_weights, params) -> None:
    """Same seed, same samples and features: on the CPU the outputs are equal (the tolerance,
    1e-6 on probabilities and 99.9 % of labels, is what a GPU's summation order may cost)."""
    scan = make_room(1, points=4_000)
    cpu, dev = predictors(dgcnn_random_weights, params)
    a, b = cpu.predict(scan, seed=5), dev.predict(scan, seed=5)
    assert a.crops == b.crops and set(a.timings) == set(b.timings)
    assert b.labels.dtype == np.int32 and b.probs.dtype == np.float32
    np.testing.assert_allclose(b.probs, a.probs, rtol=0, atol=1e-6)
    assert (a.labels == b.labels).mean() >= 0.999
    colourless = dataclasses.replace(scan.subset(np.arange(50)), rgb=None)
    np.testing.assert_allclose(dev.predict(colourless).probs, cpu.predict(colourless).probs)


def test_device_path_is_automatic_on_cuda_only(dgcnn_random_weights) -> None:
    predictor = on_cpu(dgcnn_random_weights, DGCNNParams())
    assert predictor.device_path is None and not predictor.on_device
    predictor.device = torch.device("cuda")  # what a CUDA predictor reports; nothing runs
    assert predictor.on_device
    predictor.device_path = False
    assert not predictor.on_device


@pytest.mark.slow
def test_device_path_progress_and_cancel(dgcnn_random_weights, stop_after) -> None:
    _, dev = predictors(dgcnn_random_weights, DGCNNParams(num_points=64, stride=1.0))
    scan: Scan = make_room(1, points=3_000)
    calls: list[tuple[str, float]] = []
    dev.predict(scan, progress=lambda stage, f: calls.append((stage, f)))
    assert calls[-1] == ("network", 1.0) and calls == sorted(calls)
    token = stop_after(3)
    with pytest.raises(Cancelled):
        dev.predict(scan, cancel=token)
    assert token.checks == 4
