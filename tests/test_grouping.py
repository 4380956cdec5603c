"""The shared group-by kernels against plain-Python references, on random and edge-case input."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pytest

from jointseg import grouping
from jointseg.fusion import guard
from jointseg.geometry import clustering
from jointseg.grouping import (
    cell_keys,
    compact_ids,
    group_sums,
    label_histogram,
    majority_label,
)
from jointseg.metrics import segment_majority
from jointseg.voxels import cell_majority, voxel_index


def _naive_compact(ids: list[int]) -> tuple[list[int], list[int]]:
    distinct = sorted(set(ids))
    rank = {v: i for i, v in enumerate(distinct)}
    return distinct, [rank[v] for v in ids]


def _naive_histogram(
    group: list[int], n_groups: int, labels: list[int], weights: list[float] | None = None
) -> dict[tuple[int, int], float]:
    out: dict[tuple[int, int], float] = defaultdict(float)
    for i, (g, lab) in enumerate(zip(group, labels, strict=True)):
        if lab >= 0:
            out[(g, lab)] += 1.0 if weights is None else weights[i]
    return out


def _naive_majority(
    group: list[int], n_groups: int, labels: list[int], weights: list[float] | None = None
) -> list[int]:
    hist = _naive_histogram(group, n_groups, labels, weights)
    out = []
    for g in range(n_groups):
        votes = {lab: v for (gg, lab), v in hist.items() if gg == g}
        if not votes or max(votes.values()) <= 0:
            out.append(-1)
            continue
        best = max(votes.values())
        out.append(min(lab for lab, v in votes.items() if v == best))  # ties: smaller label
    return out


@pytest.mark.parametrize(
    ("n", "low", "high"),
    [
        (1, 5, 6),  # a single id
        (50, 0, 10),  # dense
        (500, 0, 3),  # few distinct ids
        (300, -7, 8),  # negative ids
        (200, 0, 10**9),  # sparse: the sorting path
        (200, -(10**12), 10**12),  # sparse and negative, beyond int32
        (1000, 10**6, 10**6 + 40),  # dense but far from zero
    ],
)
def test_compact_ids_matches_a_sorted_renumbering(n: int, low: int, high: int) -> None:
    rng = np.random.default_rng(n + low % 97)
    ids = rng.integers(low, high, n)
    distinct, inverse = compact_ids(ids)
    want_distinct, want_inverse = _naive_compact(ids.tolist())
    assert distinct.tolist() == want_distinct
    assert inverse.tolist() == want_inverse
    assert distinct.dtype == np.int64 and inverse.dtype == np.int64
    np.testing.assert_array_equal(distinct[inverse], ids)


@pytest.mark.parametrize("high", [3, 60, 10**7])
def test_compact_ids_dense_and_sorting_paths_agree(
    monkeypatch: pytest.MonkeyPatch, high: int
) -> None:
    ids = np.random.default_rng(high).integers(-2, high, 400)
    results = []
    for factor in (0, 10**9):  # 0: always sort; huge: always the lookup table
        monkeypatch.setattr(grouping, "DENSE_SPAN_FACTOR", factor)
        results.append(compact_ids(ids))
    for got, want in zip(results[0], results[1], strict=True):
        np.testing.assert_array_equal(got, want)
    assert results[0][1].tolist() == _naive_compact(ids.tolist())[1]


def test_compact_ids_edge_cases() -> None:
    distinct, inverse = compact_ids(np.zeros(0, dtype=np.int64))
    assert distinct.shape == inverse.shape == (0,)
    distinct, inverse = compact_ids(np.array([3, 3, 3], dtype=np.int32))
    assert distinct.tolist() == [3] and inverse.tolist() == [0, 0, 0]
    ids = np.array([4, 1, 4])
    compact_ids(ids)
    assert ids.tolist() == [4, 1, 4]  # input untouched
    with pytest.raises(TypeError, match="integers"):
        compact_ids(np.array([0.5, 1.0]))
    with pytest.raises(ValueError, match="1-D"):
        compact_ids(np.zeros((2, 2), dtype=np.int64))


def test_old_renumbering_names_are_the_kernel() -> None:
    ids = np.random.default_rng(2).integers(0, 40, 200)
    np.testing.assert_array_equal(clustering.compact(ids), compact_ids(ids)[1])
    for got, want in zip(guard.compact_ids(ids), compact_ids(ids), strict=True):
        np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("size", [0.05, 0.3, 1.0, 7.0])
def test_cell_keys_group_exactly_the_points_of_one_cell(size: float) -> None:
    rng = np.random.default_rng(int(size * 100))
    xyz = rng.normal(0.0, 2.0, (2000, 3)) + [100.0, -50.0, 3.0]
    keys, n_keys = cell_keys(xyz, size)
    lo = xyz.min(axis=0)
    cells = [tuple(math.floor(v) for v in (p - lo) / size) for p in xyz]
    by_cell: dict[tuple[int, ...], set[int]] = defaultdict(set)
    for cell, key in zip(cells, keys.tolist(), strict=True):
        by_cell[cell].add(key)
    assert all(len(k) == 1 for k in by_cell.values())  # one key per cell ...
    assert len({next(iter(k)) for k in by_cell.values()}) == len(by_cell)  # ... and per key
    assert keys.dtype == np.int64 and keys.min() >= 0 and keys.max() < n_keys
    spans = np.array(cells).max(axis=0) + 1
    assert n_keys == int(np.prod(spans))


def test_cell_keys_origin_edge_cases() -> None:
    xyz = np.array([[0.1, 0.2, 0.3], [0.15, 0.2, 0.3], [2.0, 0.2, 0.3]])
    keys, n_keys = cell_keys(xyz, 0.5)
    assert keys[0] == keys[1] != keys[2]
    same, _ = cell_keys(xyz, 0.5, origin=xyz.min(axis=0))
    np.testing.assert_array_equal(same, keys)
    shifted, _ = cell_keys(xyz, 0.5, origin=np.array([-0.35, 0.0, 0.0]))
    assert shifted[0] != shifted[1]  # 0.45 and 0.5 from the origin: different cells now
    with pytest.raises(ValueError, match="origin"):
        cell_keys(xyz, 0.5, origin=np.array([1.0, 0.0, 0.0]))
    empty, n_empty = cell_keys(np.zeros((0, 3)), 0.5)
    assert empty.shape == (0,) and n_empty == 0
    single, n_single = cell_keys(np.array([[5.0, 5.0, 5.0]]), 0.5)
    assert single.tolist() == [0] and n_single == 1
    flat, n_flat = cell_keys(np.array([[0.0, 0.0], [1.0, 3.0]]), 1.0)  # 2-D grids too
    assert flat.tolist() == [0, 7] and n_flat == 8


def test_group_sums_matches_a_loop() -> None:
    rng = np.random.default_rng(3)
    group = rng.integers(0, 7, 300)
    values = rng.random((300, 4)).astype(np.float32)
    sums = group_sums(group, 9, values)  # groups 7 and 8 are empty
    want = np.zeros((9, 4))
    for g, row in zip(group, values.astype(np.float64), strict=True):
        want[g] += row
    assert sums.shape == (9, 4) and sums.dtype == np.float64
    np.testing.assert_allclose(sums, want, rtol=1e-12)
    assert not sums[7:].any()
    assert group_sums(group, 7, np.zeros((300, 0))).shape == (7, 0)
    assert group_sums(np.zeros(0, np.int64), 2, np.zeros((0, 3))).tolist() == [[0.0] * 3] * 2


@pytest.mark.parametrize("seed", range(5))
def test_label_histogram_and_majority_match_a_loop(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, n_groups = int(rng.integers(1, 400)), int(rng.integers(1, 30))
    group = rng.integers(0, n_groups, n)
    labels = rng.integers(-1, 6, n)  # -1: unlabelled
    hist = label_histogram(group, n_groups, labels, 6)
    want = _naive_histogram(group.tolist(), n_groups, labels.tolist())
    assert hist.shape == (n_groups, 6) and hist.dtype == np.int64
    assert {k: v for k, v in np.ndenumerate(hist) if v} == dict(want)
    majority = majority_label(group, n_groups, labels)
    assert majority.tolist() == _naive_majority(group.tolist(), n_groups, labels.tolist())
    weights = rng.random(n)
    weighted = majority_label(group, n_groups, labels, 6, weights=weights)
    naive = _naive_majority(group.tolist(), n_groups, labels.tolist(), weights.tolist())
    assert weighted.tolist() == naive


def test_majority_edge_cases() -> None:
    # ties go to the smaller label; a group without labelled points gets -1
    assert majority_label(np.array([0, 0, 1, 2]), 4, np.array([3, 1, -1, 0])).tolist() == [
        1,
        -1,
        0,
        -1,
    ]
    # nothing labelled at all, and nothing at all
    assert majority_label(np.array([0, 1]), 2, np.array([-1, -1])).tolist() == [-1, -1]
    assert majority_label(np.zeros(0, np.int64), 3, np.zeros(0, np.int64)).tolist() == [-1] * 3
    # a single group
    assert majority_label(np.zeros(5, np.int64), 1, np.array([2, 2, 7, 7, 7])).tolist() == [7]
    # weights decide over counts
    weights = np.array([1.0, 1.0, 5.0])
    assert majority_label(np.zeros(3, np.int64), 1, np.array([0, 0, 1]), weights=weights) == [1]
    with pytest.raises(ValueError, match="does not fit"):
        label_histogram(np.zeros(2, np.int64), 1, np.array([0, 13]), 13)
    with pytest.raises(ValueError, match="one length"):
        label_histogram(np.zeros(2, np.int64), 1, np.array([0]))
    labels = np.array([-1, 2, 2])
    label_histogram(np.zeros(3, np.int64), 1, labels)
    assert labels.tolist() == [-1, 2, 2]  # input untouched


def test_callers_agree_with_the_kernel() -> None:
    rng = np.random.default_rng(4)
    xyz = rng.random((3000, 3)) * 4.0
    labels = rng.integers(-1, 13, 3000)
    inverse, centroids = voxel_index(xyz, 0.5)
    np.testing.assert_array_equal(
        cell_majority(labels, inverse, len(centroids)),
        majority_label(inverse, len(centroids), labels),
    )
    for cell in range(0, len(centroids), 17):
        np.testing.assert_allclose(centroids[cell], xyz[inverse == cell].mean(axis=0))
    segments = rng.integers(0, 40, 3000) * 1000  # sparse ids
    oracle = segment_majority(labels, segments)
    _, seg = np.unique(segments, return_inverse=True)
    per_segment = _naive_majority(seg.tolist(), int(seg.max()) + 1, labels.tolist())
    assert oracle.tolist() == [per_segment[s] for s in seg]
    assert oracle.dtype == np.int32


def test_group_quantiles_are_each_groups_lower_quantile_and_nan_when_empty() -> None:
    from jointseg.grouping import group_quantiles

    rng = np.random.default_rng(4)
    group = rng.integers(0, 5, 2000)
    group[group == 3] = 4  # group 3 is empty
    values = rng.normal(size=2000)
    low, mid, high = group_quantiles(group, 6, values, (0.02, 0.5, 0.98))
    for g in range(6):
        mine = values[group == g]
        got = [low[g], mid[g], high[g]]
        if mine.size == 0:
            assert np.isnan(got).all()
        else:
            want = np.quantile(mine, [0.02, 0.5, 0.98], method="lower")
            assert np.allclose(got, want)
    assert all(np.isnan(q).all() for q in group_quantiles(group[:0], 2, values[:0], (0.5,)))


def _reference_cell_keys(
    xyz: np.ndarray, size: float, origin: np.ndarray | None = None, aligned: bool = False
) -> tuple[np.ndarray, int]:
    """cell_keys as first written: the arithmetic (and its dtypes) the faster one must keep."""
    if aligned:
        cells = np.floor(xyz / size).astype(np.int64)
        cells -= cells.min(axis=0)
    else:
        lo = xyz.min(axis=0) if origin is None else origin
        cells = np.floor((xyz - lo) / size).astype(np.int64)
    dims = cells.max(axis=0) + 1
    keys = cells[:, 0]
    for axis in range(1, cells.shape[1]):
        keys = keys * dims[axis] + cells[:, axis]
    return keys, int(dims.prod())


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int32])
@pytest.mark.parametrize("size", [0.013, np.float64(0.013), np.float32(0.013), 2])
def test_cell_keys_keep_the_plain_arithmetic_to_the_bit(dtype: type, size: float) -> None:
    rng = np.random.default_rng(11)
    xyz: np.ndarray = (rng.normal(0.0, 1.0, (5000, 3)) * (1 if dtype != np.int32 else 100)).astype(
        dtype
    )
    for kwargs in ({}, {"aligned": True}, {"origin": xyz.min(axis=0) - 1}):
        keys, n_keys = cell_keys(xyz, size, **kwargs)
        want, n_want = _reference_cell_keys(xyz, size, **kwargs)
        assert keys.dtype == want.dtype == np.int64
        np.testing.assert_array_equal(keys, want)
        assert n_keys == n_want
    flat = xyz[:, :2]
    np.testing.assert_array_equal(cell_keys(flat, size)[0], _reference_cell_keys(flat, size)[0])


@pytest.mark.parametrize(
    ("n", "low", "high"),
    [(5000, 0, 10**9), (20_000, -(10**15), 10**15), (3000, 0, 4 * 3000), (1, 7, 8), (2, 0, 2**62)],
)
def test_compact_ids_sorting_paths_match_numpy_unique(n: int, low: int, high: int) -> None:
    ids = np.random.default_rng(n).integers(low, high, n, dtype=np.int64)
    want_distinct, want_inverse = np.unique(ids, return_inverse=True)
    for factor in (0, grouping.DENSE_SPAN_FACTOR, 10**9):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(grouping, "DENSE_SPAN_FACTOR", factor)
            if factor == 10**9 and high - low > 10**8:
                continue  # the lookup table would be the span's size
            distinct, inverse = compact_ids(ids)
        assert distinct.dtype == inverse.dtype == np.int64
        np.testing.assert_array_equal(distinct, want_distinct)
        np.testing.assert_array_equal(inverse, want_inverse)


@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.uint8, np.int16])
@pytest.mark.parametrize("n", [0, 1, 2, 1000])
def test_sorted_distinct_is_numpy_unique(dtype: type, n: int) -> None:
    ids: np.ndarray = np.random.default_rng(n).integers(0, 100, n).astype(dtype)
    got = grouping.sorted_distinct(ids)
    want = np.unique(ids)
    assert got.dtype == want.dtype
    np.testing.assert_array_equal(got, want)
    with pytest.raises(TypeError, match="integers"):
        grouping.sorted_distinct(np.array([0.5]))


def test_voxel_count_and_cell_centroids_are_voxel_index() -> None:
    from jointseg.voxels import cell_centroids, voxel_count

    xyz = np.random.default_rng(12).normal(0.0, 1.0, (4000, 3))
    for voxel in (0.05, 0.3, 5.0):
        inverse, centroids = voxel_index(xyz, voxel)
        count, keys = voxel_count(xyz, voxel)
        assert count == len(centroids)
        got_inverse, got_centroids = cell_centroids(xyz, keys)
        np.testing.assert_array_equal(got_inverse, inverse)
        np.testing.assert_array_equal(got_centroids, centroids)


@pytest.mark.parametrize("case", ["plain", "ties", "signed_zeros", "nan", "ints", "one"])
def test_group_quantiles_sort_is_lexsorts_to_the_bit(case: str) -> None:
    rng = np.random.default_rng(13)
    n = 1 if case == "one" else 5000
    group = rng.integers(0, 300, n)
    values = rng.normal(size=n)
    if case == "ties":
        values = np.round(values, 1)
    elif case == "signed_zeros":
        values[rng.random(n) < 0.3] = 0.0
        values[rng.random(n) < 0.3] = -0.0
    elif case == "nan":
        values[rng.random(n) < 0.05] = np.nan
    elif case == "ints":
        values = rng.integers(-5, 5, n)
    want = values[np.lexsort((values, group))]
    got = grouping._sorted_within_groups(group, values)
    assert got.dtype == want.dtype
    assert got.tobytes() == want.tobytes()  # -0.0 and 0.0 told apart, NaNs in place
