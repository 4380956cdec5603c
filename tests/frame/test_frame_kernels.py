"""The frame stage's fast kernels give what the plain code they replaced gives, bit for bit: the
stray rules from histograms and cell counts, the work frame's columns, the strays' nearest kept
points, the colour decision from integer counts and the sample moved after it is drawn."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from jointseg.frame import colour, decide, gravity, strays
from jointseg.frame.colour import CONSTANT_STD, decide_colour
from jointseg.frame.decide import nearest_kept, rotation_about, rotation_to_z


def reference_bulk_mask(values: np.ndarray) -> np.ndarray:
    """The bulk rule as first written: the whole array's median, a mask over every point."""
    lo, hi = float(values.min()), float(values.max())
    if hi - lo <= strays.GAP_M:
        return np.ones(len(values), dtype=bool)
    bins = int(np.ceil((hi - lo) / strays.BIN_M)) + 1
    idx = ((values - lo) / strays.BIN_M).astype(np.int64)
    counts = np.bincount(idx, minlength=bins)
    occupied = counts >= max(2.0, strays.OCCUPIED_SHARE * len(values))
    start = stop = int((np.median(values) - lo) / strays.BIN_M)
    gap = int(np.ceil(strays.GAP_M / strays.BIN_M))
    occ = np.flatnonzero(occupied)
    left, right = occ[occ <= start], occ[occ >= stop]
    if len(left):
        jumps = np.flatnonzero(np.diff(left[::-1]) < -gap)
        start = int(left[::-1][jumps[0]] if len(jumps) else left[0])
    if len(right):
        jumps = np.flatnonzero(np.diff(right) > gap)
        stop = int(right[jumps[0]] if len(jumps) else right[-1])
    return (idx > start - gap) & (idx < stop + gap)


def reference_isolated(xyz: np.ndarray) -> np.ndarray:
    """Isolation as first written: a sort of the cell keys, 27 look-ups per occupied cell."""
    cells = np.floor((xyz - xyz.min(axis=0)) / strays.CELL_M).astype(np.int64) + 1
    dims = cells.max(axis=0) + 2

    def key(c: np.ndarray) -> np.ndarray:
        return (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]

    keys, inverse, counts = np.unique(key(cells), return_inverse=True, return_counts=True)
    keys_xyz = np.stack(np.unravel_index(keys, tuple(dims)), axis=1)
    total = np.zeros(len(keys), dtype=np.int64)
    for d in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T:
        k = key(keys_xyz + d)
        pos = np.clip(np.searchsorted(keys, k), 0, len(keys) - 1)
        total += np.where(keys[pos] == k, counts[pos], 0)
    return (total < strays.MIN_NEIGHBOURS)[inverse.reshape(-1)]


def reference_strays(xyz: np.ndarray) -> np.ndarray:
    stray = np.zeros(len(xyz), dtype=bool)
    if len(xyz) < 100:
        return stray
    for axis in range(3):
        stray |= ~reference_bulk_mask(xyz[:, axis])
    if stray.mean() > strays.MAX_SHARE:
        stray[:] = False
    lonely = reference_isolated(xyz)
    rest = ~(stray | lonely)
    if lonely.mean() <= strays.MAX_SHARE and rest.any():
        lo = xyz[rest].min(axis=0) - strays.BOX_TOLERANCE_M
        hi = xyz[rest].max(axis=0) + strays.BOX_TOLERANCE_M
        idx = np.flatnonzero(lonely)
        stray[idx[np.any((xyz[idx] < lo) | (xyz[idx] > hi), axis=1)]] = True
    return stray


def cloud(seed: int, n: int = 20_000, *, far: int = 30, lonely: int = 15) -> np.ndarray:
    """A room-sized box of points, some far beyond a gap, some alone just outside it."""
    rng = np.random.default_rng(seed)
    room = rng.uniform([0, 0, 0], [rng.uniform(3, 8), rng.uniform(3, 8), 2.8], (n, 3))
    room = np.round(room, rng.integers(2, 5))  # scanners repeat values: ties in the medians
    away = room[:far] + rng.choice([-1, 1], (far, 3)) * rng.uniform(1.5, 6, (far, 3))
    alone = room.max(axis=0) + rng.uniform(0.35, 0.9, (lonely, 3)) * rng.choice([0, 1], (lonely, 3))
    return np.r_[room, away, alone, room[:3] - 0.2]


@pytest.mark.parametrize("n", [1, 2, 7, 100, 1001, 5000])
def test_the_median_from_the_bins_is_numpys(n: int) -> None:
    rng = np.random.default_rng(n)
    base = np.round(rng.normal(3.0, 2.0, n), 1)
    values: np.ndarray
    for values in (base, base.astype(np.float32)):
        lo = values.min()
        idx = ((values - lo) / strays.BIN_M).astype(np.int64)
        got = np.asarray(strays.median_by_bins(values, idx, np.bincount(idx)))
        expected = np.asarray(np.median(values))
        assert got == expected and got.dtype == expected.dtype


@pytest.mark.parametrize("seed", range(6))
def test_the_stray_rules_give_the_plain_codes_points(seed: int) -> None:
    xyz = cloud(seed)
    expected = reference_strays(xyz)
    assert expected.any() and not expected.all()
    assert np.array_equal(strays.find_strays(xyz), expected)
    assert np.array_equal(
        strays.find_strays(xyz.astype(np.float32)), reference_strays(xyz.astype(np.float32))
    )
    for axis in range(3):
        assert np.array_equal(strays.bulk_mask(xyz[:, axis]), reference_bulk_mask(xyz[:, axis]))
    assert np.array_equal(strays.isolated_mask(xyz), reference_isolated(xyz))


def test_isolation_on_a_sparse_grid_is_the_dense_grids(monkeypatch: pytest.MonkeyPatch) -> None:
    xyz = np.r_[cloud(7), [[400.0, -300.0, 90.0]]]  # one point far out: a huge, empty grid
    expected = reference_isolated(xyz)
    assert np.array_equal(strays.isolated_mask(xyz), expected)
    monkeypatch.setattr(strays, "DENSE_CELLS", 0)
    assert np.array_equal(strays.isolated_mask(cloud(8)), reference_isolated(cloud(8)))


def test_clean_and_tiny_clouds_have_no_strays() -> None:
    xyz = cloud(9, far=0, lonely=0)[:-3]
    assert not strays.find_strays(xyz).any() and not reference_strays(xyz).any()
    assert not strays.find_strays(xyz[:99]).any()


@pytest.mark.parametrize("up", list(gravity.AXES))
def test_the_work_columns_are_the_products(up: str) -> None:
    rng = np.random.default_rng(3)
    xyz = rng.normal(0, 5, (5000, 3))
    centre = np.median(xyz, axis=0)
    tilted = rotation_to_z(gravity.AXES[up]) @ rotation_about(np.array([1.0, 2.0, 0.0]), 4.0)
    for rotation in (rotation_to_z(gravity.AXES[up]), tilted):
        for metres in (1.0, 0.001, 0.3048):
            expected = ((xyz - centre) @ rotation.T) * metres
            got = strays.work_columns(xyz, centre, rotation, metres)
            assert got.shape == (3, len(xyz)) and got.flags.c_contiguous
            assert np.array_equal(got, expected.T)


def reference_nearest(kept: np.ndarray, lone: np.ndarray) -> np.ndarray:
    return cKDTree(kept).query(lone, workers=-1)[1]


def test_strays_take_the_nearest_kept_point_the_full_tree_gives(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    rng = np.random.default_rng(4)
    kept = rng.uniform([0, 0, 0], [9, 7, 3], (80_000, 3))
    above = np.c_[rng.uniform(0, 9, (200, 2)), rng.uniform(5, 6, 200)]
    beside = np.c_[rng.uniform(9.3, 9.6, 40), rng.uniform(0, 7, 40), rng.uniform(0, 3, 40)]
    lone = np.r_[above, beside]
    full = decide._full_tree_nearest
    asked: list[int] = []

    def counted(k: np.ndarray, s: np.ndarray) -> np.ndarray:
        asked.append(1)
        return full(k, s)

    monkeypatch.setattr(decide, "_full_tree_nearest", counted)
    assert np.array_equal(nearest_kept(kept, lone), reference_nearest(kept, lone))
    assert not asked  # the candidates' tree answered
    # ties (a duplicated point) go to the full tree, which decides them as before
    twins = np.r_[kept, kept[:5000]]
    assert np.array_equal(
        nearest_kept(twins, kept[:10] + 1e-3), reference_nearest(twins, kept[:10] + 1e-3)
    )
    # many strays, or a small scan: the full tree itself
    many = rng.uniform(-2, 12, (3000, 3))
    assert np.array_equal(nearest_kept(kept, many), reference_nearest(kept, many))
    assert np.array_equal(nearest_kept(kept[:500], lone), reference_nearest(kept[:500], lone))


def reference_colour(rgb: np.ndarray, correct: bool = True) -> tuple[str, np.ndarray | None]:
    """The colour decision as first written: float moments of the sample."""
    sample = rgb[:: max(1, len(rgb) // 200_000)].astype(np.float64)
    if float(sample.std(axis=0).max()) < CONSTANT_STD:
        return "constant", None
    if not correct:
        return "rgb", None
    mean = sample.mean(axis=0) + 1e-6
    gains = np.ones(3)
    red, blue = mean[0] / mean[1], mean[2] / mean[1]
    gains[0] = float(np.clip(red, *colour.RED_RANGE)) / red
    gains[2] = float(np.clip(blue, *colour.BLUE_RANGE)) / blue
    light = float((mean * gains).mean())
    if light < colour.LOW:
        gains *= colour.TARGET_LOW / light
    elif light > colour.HIGH:
        gains *= colour.TARGET_HIGH / light
    return ("rgb", None) if np.allclose(gains, 1.0) else ("rgb", gains)


@pytest.mark.parametrize(
    "make",
    [
        lambda r: r.integers(0, 256, (300_000, 3)).astype(np.uint8),
        lambda r: r.integers(30, 90, (50_001, 3)).astype(np.uint8),  # dim: gains
        lambda r: np.full((1000, 3), 128, np.uint8),  # constant
        lambda r: (128 + 2 * (np.arange(1000) % 2))[:, None].repeat(3, 1).astype(np.uint8),  # std 1
        lambda r: (128 + (r.random((999, 3)) < 0.3)).astype(np.uint8),  # std below 1
        lambda r: r.integers(0, 65536, (20_000, 3)).astype(np.uint16),
        lambda r: r.uniform(0, 255, (20_000, 3)),  # floats: the float moments themselves
    ],
)
def test_the_colour_decision_is_the_float_moments(make) -> None:
    rgb = make(np.random.default_rng(5))
    for correct in (True, False):
        kind, gains = reference_colour(rgb, correct)
        decision = decide_colour(rgb, correct)
        assert decision.kind == kind
        if gains is None or decision.gains is None:
            assert gains is None and decision.gains is None
        else:
            assert np.array_equal(decision.gains, gains)


def test_the_sample_moved_after_drawing_is_the_sample_of_the_moved_scan() -> None:
    rng = np.random.default_rng(6)
    for n in (30_000, 250_000):
        xyz = rng.uniform([0, 0, 0], [6, 5, 3], (n, 3))
        centre = np.median(xyz[::10], axis=0)
        a = gravity.frame_sample(xyz - centre, np.random.default_rng(0))
        b = gravity.frame_sample(xyz, np.random.default_rng(0), centre=centre)
        assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.normals, b.normals)
        assert np.array_equal(a.directions, b.directions)
