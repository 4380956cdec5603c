"""Metrics against hand-computed values and the paper's conventions ('/' for absent classes)."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX, CLASS_NAMES
from jointseg.metrics import (
    confusion_matrix,
    evaluate,
    segment_majority,
    segment_purity,
)


def test_confusion_matrix_counts_pairs_and_ignores_unlabelled() -> None:
    gt = np.array([0, 0, 1, 1, 1, -1, 2])
    pred = np.array([0, 1, 1, 1, 0, 2, -1])
    cm = confusion_matrix(gt, pred, num_classes=3)
    assert cm.shape == (3, 4)
    assert cm[0].tolist() == [1, 1, 0, 0]
    assert cm[1].tolist() == [1, 2, 0, 0]
    # the invalid prediction (-1) for a class-2 point is a miss in the last column
    assert cm[2].tolist() == [0, 0, 0, 1]
    assert cm.sum() == 6  # the unlabelled point is not counted


def test_evaluate_hand_computed_iou_and_absent_classes() -> None:
    ceiling, floor, wall = CLASS_INDEX["ceiling"], CLASS_INDEX["floor"], CLASS_INDEX["wall"]
    gt = np.array([ceiling] * 4 + [floor] * 4 + [-1] * 3)
    pred = np.array([ceiling] * 3 + [floor] + [floor] * 3 + [wall] + [ceiling] * 3)
    m = evaluate(gt, pred)
    # ceiling: TP 3, FN 1, FP 0 -> 3/4; floor: TP 3, FP 1, FN 1 -> 3/5; wall: TP 0, FP 1 -> 0
    assert m.per_class_iou["ceiling"] == pytest.approx(0.75)
    assert m.per_class_iou["floor"] == pytest.approx(0.6)
    assert m.per_class_iou["wall"] == 0.0
    # absent from both ground truth and prediction -> None, left out of the mean
    assert m.per_class_iou["chair"] is None
    assert m.miou == pytest.approx((0.75 + 0.6 + 0.0) / 3)
    # accuracy is undefined for wall (no ground truth), so mAcc averages ceiling and floor
    assert m.per_class_acc["wall"] is None
    assert m.macc == pytest.approx(0.75)
    assert m.oa == pytest.approx(6 / 8)
    assert m.n_points == 8
    assert list(m.per_class_iou) == list(CLASS_NAMES)


def test_evaluate_perfect_prediction_scores_one() -> None:
    rng = np.random.default_rng(1)
    gt = rng.integers(0, 13, size=1000)
    m = evaluate(gt, gt.copy())
    assert m.miou == pytest.approx(1.0)
    assert m.macc == pytest.approx(1.0)
    assert m.oa == pytest.approx(1.0)


def test_evaluate_all_unlabelled_gives_no_scores() -> None:
    m = evaluate(np.full(5, -1), np.zeros(5, dtype=int))
    assert m.oa is None and m.miou is None and m.n_points == 0


def test_evaluate_rejects_mismatched_lengths() -> None:
    with pytest.raises(ValueError, match="equal length"):
        evaluate(np.zeros(3, dtype=int), np.zeros(4, dtype=int))


def test_segment_purity_hand_computed() -> None:
    labels = np.array([1, 1, 1, 2, 2, 2, 2, -1])
    segments = np.array([10, 10, 10, 10, 7, 7, 7, 7])
    # segment 10: majority 1, one class-2 point is impure; segment 7: all class 2
    assert segment_purity(labels, segments) == pytest.approx(6 / 7)
    assert segment_majority(labels, segments).tolist() == [1, 1, 1, 1, 2, 2, 2, 2]


def test_segment_purity_one_segment_per_point_is_perfect_and_one_segment_is_majority() -> None:
    rng = np.random.default_rng(0)
    labels = rng.choice([0, 1, 2], size=500, p=[0.6, 0.3, 0.1])
    assert segment_purity(labels, np.arange(500)) == 1.0
    assert segment_purity(labels, np.zeros(500, dtype=int)) == pytest.approx(np.mean(labels == 0))


def test_segment_purity_needs_labels() -> None:
    with pytest.raises(ValueError, match="labelled"):
        segment_purity(np.full(4, -1), np.arange(4))
