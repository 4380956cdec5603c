"""fuse() on small hand-made arrays: the paper's rule exactly, the label transfer, the soft vote,
the guard, and the errors for malformed input."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from jointseg.classes import NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.fusion import FusionParams, fuse

PAPER = FusionParams(mode="paper")


def probs_for(labels: np.ndarray, top: np.ndarray, second: np.ndarray | None = None) -> np.ndarray:
    """One-row-per-point probabilities: ``top`` on the label, ``second`` on second[:, 0]."""
    n = len(labels)
    probs = np.zeros((n, NUM_CLASSES))
    probs[np.arange(n), labels] = top
    if second is not None:
        probs[np.arange(n), second[:, 0].astype(int)] = second[:, 1]
    rest = (1 - probs.sum(axis=1)) / (NUM_CLASSES - np.count_nonzero(probs, axis=1))
    return np.where(probs > 0, probs, rest[:, None])


# segment 7: wall 60 %, window 20 %, door 10 %, table 10 %
# segment 42: floor 40 %, ceiling 30 %, clutter 30 %
SEGMENTS = np.array([7] * 10 + [42] * 10)
LABELS = np.array([2, 2, 2, 2, 2, 2, 5, 5, 6, 7] + [1, 1, 1, 1, 0, 0, 0, 12, 12, 12])
XYZ = np.zeros((20, 3))


@pytest.mark.parametrize(
    ("ratio", "expected"),
    [
        # every label's share is at least 0: nothing changes
        (0.0, LABELS),
        # below 15 %: door and table (10 %) become wall; window (20 %) stays
        (0.15, [2, 2, 2, 2, 2, 2, 5, 5, 2, 2] + [1, 1, 1, 1, 0, 0, 0, 12, 12, 12]),
        # below 25 %: window goes too; ceiling and clutter (30 %) stay
        (0.25, [2] * 10 + [1, 1, 1, 1, 0, 0, 0, 12, 12, 12]),
        # below 35 %: ceiling and clutter become floor, whose own 40 % stays
        (0.35, [2] * 10 + [1] * 10),
        (1.0, [2] * 10 + [1] * 10),
    ],
)
def test_paper_rule_replaces_labels_below_the_ratio_by_the_majority(ratio, expected) -> None:
    result = fuse(XYZ, SEGMENTS, LABELS, params=FusionParams(mode="paper", ratio_threshold=ratio))
    np.testing.assert_array_equal(result.labels, expected)
    assert result.labels.dtype == np.int32
    np.testing.assert_array_equal(result.segment_ids, [7, 42])
    np.testing.assert_array_equal(result.segment_label, [2, 1])
    np.testing.assert_allclose(result.segment_share, [0.6, 0.4])
    np.testing.assert_array_equal(result.network_labels, LABELS)
    assert not result.segment_kept.any() and not result.segment_split.any()


def test_paper_rule_breaks_a_tied_majority_towards_the_lower_class() -> None:
    # door and wall 3/7 each, below the ratio 0.5 like sofa's 1/7: all become L_max = wall
    labels = np.array([6, 6, 6, 2, 2, 2, 9])
    result = fuse(np.zeros((7, 3)), np.zeros(7, int), labels, params=PAPER)
    np.testing.assert_array_equal(result.labels, [2] * 7)


def test_inputs_are_not_mutated_and_confidence_is_defined() -> None:
    labels, segments = LABELS.copy(), SEGMENTS.copy()
    result = fuse(XYZ, segments, labels, params=FusionParams(mode="paper", ratio_threshold=0.25))
    np.testing.assert_array_equal(labels, LABELS)
    np.testing.assert_array_equal(segments, SEGMENTS)
    # without probabilities: mean of (label kept ? 1 : 0) and the fused label's share
    assert result.confidence.dtype == np.float32
    assert result.confidence[0] == pytest.approx(0.5 * (1 + 0.6))  # wall kept
    assert result.confidence[6] == pytest.approx(0.5 * (0 + 0.6))  # window -> wall
    assert result.confidence[14] == pytest.approx(0.5 * (1 + 0.3))  # ceiling kept
    np.testing.assert_array_equal(result.changed, result.labels != LABELS)


def test_labels_reach_the_segmented_points_from_a_subsampled_cloud() -> None:
    rng = np.random.default_rng(0)
    xyz = rng.uniform(0, 4, (2000, 3))
    truth = np.where(xyz[:, 0] < 2, 2, 7)  # wall left, table right
    sub = rng.choice(len(xyz), 300, replace=False)
    segments = (xyz[:, 0] >= 2).astype(np.int64)
    result = fuse(
        xyz, segments, truth[sub], params=FusionParams(mode="paper"), network_xyz=xyz[sub]
    )
    # nearest sub-sampled point's label, computed by brute force
    nearest = np.argmin(((xyz[:, None, :] - xyz[sub][None]) ** 2).sum(axis=2), axis=1)
    np.testing.assert_array_equal(result.network_labels, truth[sub][nearest])
    # the vote then makes each side pure
    np.testing.assert_array_equal(result.labels, truth)


@pytest.mark.parametrize(
    ("k", "expected"),
    [(1, 5), (2, 5), (3, 6), (4, 6)],  # k=2 ties 5/6: the nearer label wins
)
def test_transfer_with_k_neighbours_takes_their_majority(k: int, expected: int) -> None:
    network_xyz = np.array([[0.0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [5, 5, 5]])
    network_labels = np.array([5, 6, 6, 0])
    params = FusionParams(mode="paper", neighbours=k)
    result = fuse([[-0.01, 0, 0]], [0], network_labels, params=params, network_xyz=network_xyz)
    assert result.network_labels.tolist() == [expected]


def test_probabilities_follow_the_transfer() -> None:
    network_xyz = np.array([[0.0, 0, 0], [1, 0, 0]])
    labels = np.array([8, 7])
    probs = probs_for(labels, np.array([0.9, 0.6]))
    result = fuse(
        np.array([[0.9, 0, 0]]),
        [0],
        labels,
        probs,
        FusionParams(mode="soft"),
        network_xyz=network_xyz,
    )
    assert result.labels.tolist() == [7]
    # the point's own probability and its one-point segment's soft share are both 0.6
    assert result.confidence[0] == pytest.approx(0.6, rel=1e-5)


def test_soft_vote_trusts_confident_minorities_where_the_hard_vote_counts_heads() -> None:
    # six hesitant 'chair' points (table close behind) and four confident 'table' points
    labels = np.array([8] * 6 + [7] * 4)
    second = np.array([[7, 0.35]] * 6 + [[8, 0.02]] * 4)
    probs = probs_for(labels, np.array([0.4] * 6 + [0.95] * 4), second)
    xyz, segments = np.zeros((10, 3)), np.zeros(10, int)
    hard = fuse(xyz, segments, labels, probs, FusionParams(mode="paper", ratio_threshold=0.5))
    soft = fuse(xyz, segments, labels, probs, FusionParams(mode="soft", ratio_threshold=0.5))
    np.testing.assert_array_equal(hard.labels, [8] * 10)
    np.testing.assert_array_equal(soft.labels, [7] * 10)
    assert soft.segment_label.tolist() == [7] and hard.segment_label.tolist() == [8]
    # the confidence uses the probabilities: a relabelled hesitant point is less sure
    assert soft.confidence[0] < soft.confidence[9]
    # without probabilities the soft vote is the hard one
    np.testing.assert_array_equal(
        fuse(xyz, segments, labels, None, FusionParams(mode="soft")).labels, hard.labels
    )


def test_guard_keeps_network_labels_on_a_segment_without_a_clear_winner() -> None:
    labels = np.array([2] * 5 + [6] * 5)
    xyz, segments = np.zeros((10, 3)), np.zeros(10, int)  # all in one cell
    paper = fuse(xyz, segments, labels, params=FusionParams(mode="paper", ratio_threshold=0.6))
    np.testing.assert_array_equal(paper.labels, [2] * 10)
    for cell in (0.5, 0.0):
        params = FusionParams(mode="guarded", ratio_threshold=0.6, guard_cell_size=cell)
        guarded = fuse(xyz, segments, labels, params=params)
        np.testing.assert_array_equal(guarded.labels, labels)
        assert guarded.segment_kept.tolist() == [cell == 0.0]
        assert guarded.segment_split.tolist() == [cell > 0.0]


def test_guard_splits_an_impure_segment_into_cells_that_vote_on_their_own() -> None:
    # one segment spanning a wall (45 wall + 5 clutter, x < 1) and a door (50 points, x > 1)
    xyz = np.zeros((100, 3))
    xyz[:50, 0] = np.linspace(0.05, 0.95, 50)
    xyz[50:, 0] = np.linspace(1.05, 1.95, 50)
    labels = np.array([2] * 45 + [12] * 5 + [6] * 50)
    segments = np.zeros(100, int)
    paper = fuse(xyz, segments, labels, params=FusionParams(mode="paper"))
    np.testing.assert_array_equal(paper.labels, [6] * 100)  # wall lost to the door
    guarded = fuse(xyz, segments, labels, params=FusionParams(mode="guarded", guard_cell_size=1.0))
    np.testing.assert_array_equal(guarded.labels, [2] * 50 + [6] * 50)
    assert guarded.segment_split.tolist() == [True]
    # segment-level outputs still describe the whole segment
    assert guarded.segment_label.tolist() == [6]
    assert guarded.segment_share[0] == pytest.approx(0.5)


def test_huge_mixed_segments_are_split_even_with_a_clear_winner() -> None:
    # segment 0: 90 % of the scan, 60 wall points (x < 1) and 30 door points (x > 1); its
    # majority (67 %) is clear but not overwhelming; ten one-point floor segments far away
    xyz = np.zeros((100, 3))
    xyz[:60, 0] = np.linspace(0.05, 0.95, 60)
    xyz[60:90, 0] = np.linspace(1.05, 1.95, 30)
    xyz[90:, 0] = 5.0
    labels = np.array([2] * 60 + [6] * 30 + [1] * 10)
    segments = np.r_[np.zeros(90, int), np.arange(1, 11)]
    paper = fuse(xyz, segments, labels, params=FusionParams(mode="paper"))
    np.testing.assert_array_equal(paper.labels, [2] * 90 + [1] * 10)
    guarded = fuse(xyz, segments, labels, params=FusionParams(mode="guarded", guard_cell_size=1.0))
    np.testing.assert_array_equal(guarded.labels, labels)
    assert guarded.segment_split.tolist() == [True] + [False] * 10
    # a segment that is not huge is voted on whole
    not_huge = FusionParams(mode="guarded", guard_cell_size=1.0, guard_huge_fraction=0.95)
    np.testing.assert_array_equal(fuse(xyz, segments, labels, params=not_huge).labels, paper.labels)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(xyz=np.zeros((4, 2))), r"xyz must have shape \(N, 3\)"),
        (dict(segments=np.zeros(3, int)), r"segments must have shape \(4,\)"),
        (dict(segments=np.zeros(4)), "segments must be integer ids"),
        (dict(segments=np.array([0, 1, -1, 0])), "non-negative, got -1"),
        (dict(network_labels=np.zeros(5, int)), r"network_labels must have shape \(4,\) like xyz"),
        (dict(network_labels=np.array([0, 1, 13, 2])), r"class indices 0..12, got 13"),
        (dict(network_labels=np.array([0, -1, 2, 2])), "got -1"),
        (dict(network_labels=np.zeros(4)), "network_labels must be integers"),
        (dict(network_probs=np.full((4, 12), 1 / 12)), r"network_probs must have shape \(4, 13\)"),
        (dict(network_probs=np.full((4, 13), np.nan)), "finite and non-negative"),
        (
            dict(network_xyz=np.zeros((3, 3))),
            r"network_labels must have shape \(3,\) like network_xyz",
        ),
        (dict(network_xyz=np.zeros((0, 3))), "network_xyz must have shape"),
    ],
)
def test_malformed_input_raises_config_error_naming_the_argument(kwargs, message) -> None:
    args = dict(
        xyz=np.zeros((4, 3)),
        segments=np.array([0, 0, 1, 1]),
        network_labels=np.array([0, 1, 2, 2]),
        network_probs=None,
    )
    network_xyz = kwargs.pop("network_xyz", None)
    args.update(kwargs)
    with pytest.raises(ConfigError, match=message):
        fuse(**args, network_xyz=network_xyz)


def test_params_reject_unknown_keys_and_bad_values() -> None:
    with pytest.raises(ValidationError, match="ratio_treshold"):
        FusionParams.model_validate({"ratio_treshold": 0.3})
    with pytest.raises(ValidationError, match="mode"):
        FusionParams(mode="average")  # type: ignore[arg-type]
    with pytest.raises(ValidationError, match="ratio_threshold"):
        FusionParams(ratio_threshold=1.5)


def test_empty_input_gives_empty_result() -> None:
    result = fuse(np.zeros((0, 3)), np.zeros(0, int), np.zeros(0, int))
    assert result.labels.shape == (0,) and result.n_segments == 0


def test_soft_fusion_never_relabels_a_point_to_a_class_the_network_ruled_out() -> None:
    # a 'wall' segment with two 'window' points: one window point gives wall 0.2, the other 0
    labels = np.array([2] * 8 + [5, 5])
    second = np.array([[5, 0.1]] * 8 + [[2, 0.2], [2, 0.0]])
    probs = probs_for(labels, np.array([0.9] * 8 + [0.8, 0.99]), second)
    xyz, segments = np.zeros((10, 3)), np.zeros(10, int)
    soft = fuse(xyz, segments, labels, probs, FusionParams(mode="soft", min_support=0.05))
    assert soft.labels.tolist() == [2] * 9 + [5]
    # without the check (and in the paper's rule, which never looks at probabilities) both go
    for params in (FusionParams(mode="soft", min_support=0.0), FusionParams(mode="paper")):
        assert fuse(xyz, segments, labels, probs, params).labels.tolist() == [2] * 10
