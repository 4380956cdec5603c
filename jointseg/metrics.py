"""Segmentation metrics as the paper reports them: per-class IoU, mIoU, mAcc, OA.

Points labelled -1 in the ground truth are ignored. A class absent from both ground truth and
prediction has no IoU (``None``, the paper's '/') and is left out of the means.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.grouping import compact_ids, majority_label


class SegmentationMetrics(BaseModel):
    """Scores of one prediction against ground truth; ``None`` marks an absent class."""

    model_config = ConfigDict(frozen=True)

    per_class_iou: dict[str, float | None]
    per_class_acc: dict[str, float | None]
    miou: float | None
    macc: float | None
    oa: float | None
    n_points: int


def _check_pair(gt: np.ndarray, pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    gt = np.asarray(gt)
    pred = np.asarray(pred)
    if gt.ndim != 1 or gt.shape != pred.shape:
        raise ValueError(
            f"ground truth and prediction must be 1-D of equal length, got {gt.shape} "
            f"and {pred.shape}"
        )
    return gt.astype(np.int64, copy=False), pred.astype(np.int64, copy=False)


def confusion_matrix(
    gt: np.ndarray, pred: np.ndarray, *, num_classes: int = NUM_CLASSES
) -> np.ndarray:
    """Count (ground truth, prediction) pairs.

    Parameters
    ----------
    gt, pred : ndarray of shape (N,), int
        Ground-truth and predicted class indices. Ground truth -1 is ignored; a prediction
        outside ``0..num_classes-1`` (e.g. -1) counts as a miss for the true class.

    Returns
    -------
    ndarray of shape (num_classes, num_classes + 1), int64
        Rows are ground truth, columns predictions; the last column counts invalid predictions.
    """
    gt, pred = _check_pair(gt, pred)
    keep = (gt >= 0) & (gt < num_classes)
    gt, pred = gt[keep], pred[keep]
    pred = np.where((pred >= 0) & (pred < num_classes), pred, num_classes)
    flat = np.bincount(gt * (num_classes + 1) + pred, minlength=num_classes * (num_classes + 1))
    return flat.reshape(num_classes, num_classes + 1)


def per_class_iou(cm: np.ndarray) -> list[float | None]:
    """IoU = TP / (TP + FP + FN) per class from a confusion matrix; ``None`` where undefined."""
    k = cm.shape[0]
    tp = np.diag(cm[:, :k]).astype(np.float64)
    fn = cm.sum(axis=1) - tp
    fp = cm[:, :k].sum(axis=0) - tp
    union = tp + fp + fn
    return [None if union[i] == 0 else float(tp[i] / union[i]) for i in range(k)]


def per_class_accuracy(cm: np.ndarray) -> list[float | None]:
    """Recall TP / (TP + FN) per class; ``None`` for a class absent from the ground truth."""
    k = cm.shape[0]
    tp = np.diag(cm[:, :k]).astype(np.float64)
    support = cm.sum(axis=1)
    return [None if support[i] == 0 else float(tp[i] / support[i]) for i in range(k)]


def _mean(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def evaluate(
    gt: np.ndarray, pred: np.ndarray, *, class_names: tuple[str, ...] = CLASS_NAMES
) -> SegmentationMetrics:
    """Per-class IoU and accuracy, mIoU, mAcc and overall accuracy of ``pred`` against ``gt``.

    Parameters
    ----------
    gt, pred : ndarray of shape (N,), int
        Ground truth (-1 = unlabelled, ignored) and prediction.

    Returns
    -------
    SegmentationMetrics
        ``oa`` and the means are ``None`` when no point is labelled.
    """
    cm = confusion_matrix(gt, pred, num_classes=len(class_names))
    iou = per_class_iou(cm)
    acc = per_class_accuracy(cm)
    # A class predicted but absent from ground truth has IoU 0 and no accuracy; one absent from
    # both has neither. Both cases follow from the counts above.
    total = int(cm.sum())
    oa = float(np.trace(cm[:, : len(class_names)]) / total) if total else None
    return SegmentationMetrics(
        per_class_iou=dict(zip(class_names, iou, strict=True)),
        per_class_acc=dict(zip(class_names, acc, strict=True)),
        miou=_mean(iou),
        macc=_mean(acc),
        oa=oa,
        n_points=total,
    )


def segment_majority(labels: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Majority ground-truth label of each point's segment (-1 where a segment has no labels).

    This is the best any per-segment vote can do, hence the 'oracle' of the fusion stage.

    Parameters
    ----------
    labels : ndarray of shape (N,), int
        Ground truth, -1 = unlabelled (not counted).
    segments : ndarray of shape (N,), int
        Segment id per point (any non-negative integers).

    Returns
    -------
    ndarray of shape (N,), int32
    """
    labels, segments = _check_pair(labels, segments)
    if labels.size == 0:
        return np.empty(0, dtype=np.int32)
    if segments.min() < 0:
        raise ValueError("segment ids must be non-negative")
    _, seg = compact_ids(segments)
    majority = majority_label(seg, int(seg.max()) + 1, labels)
    return majority[seg].astype(np.int32)


def segment_purity(labels: np.ndarray, segments: np.ndarray) -> float:
    """Share of labelled points whose segment's majority ground-truth label equals their own.

    The upper bound of any segment vote: 1.0 means no segment mixes classes.

    Parameters
    ----------
    labels : ndarray of shape (N,), int
        Ground truth, -1 = unlabelled (ignored).
    segments : ndarray of shape (N,), int
        Segment id per point.

    Returns
    -------
    float in [0, 1]

    Raises
    ------
    ValueError
        When no point is labelled.
    """
    labels = np.asarray(labels)
    majority = segment_majority(labels, segments)
    valid = labels >= 0
    if not valid.any():
        raise ValueError("segment purity needs at least one labelled point")
    return float(np.mean(majority[valid] == labels[valid]))
