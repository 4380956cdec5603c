"""How well objects were found: instance precision, recall and F1 per class at IoU >= 0.5.

A found object matches a true one of the same class when their point sets overlap with an
intersection over union of at least one half; at that threshold a true object has at most one
match, so no assignment search is needed.
"""

from __future__ import annotations

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.grouping import rows_by_id


def match_counts(
    truth_ids: np.ndarray,
    truth_labels: np.ndarray,
    found_ids: np.ndarray,
    found_labels: np.ndarray,
    *,
    classes: tuple[int, ...],
    threshold: float = 0.5,
    min_points: int = 30,
) -> dict[int, tuple[int, int, int]]:
    """(true positives, false positives, false negatives) per class.

    Parameters
    ----------
    truth_ids, found_ids : ndarray of shape (N,), int
        Object id per point; ids < 0 (or 0 for ScanNet-style truth, pass them as -1) are none.
    truth_labels, found_labels : ndarray of shape (N,), int
        The class of each point in each labelling; an object's class is its points' majority.
    min_points : int
        True objects with fewer points are not counted (they cannot be found as objects).
    """
    out = {}
    for cls in classes:
        t = _objects(truth_ids, truth_labels, cls, min_points)
        f = _objects(found_ids, found_labels, cls, 1)
        matched_t: set[int] = set()
        tp = 0
        for f_rows in f.values():
            for t_id, t_rows in t.items():
                if t_id in matched_t:
                    continue
                inter = np.intersect1d(f_rows, t_rows, assume_unique=True).size
                if inter and inter / (f_rows.size + t_rows.size - inter) >= threshold:
                    matched_t.add(t_id)
                    tp += 1
                    break
        out[cls] = (tp, len(f) - tp, len(t) - tp)
    return out


def _objects(
    ids: np.ndarray, labels: np.ndarray, cls: int, min_points: int
) -> dict[int, np.ndarray]:
    """Rows of each object whose majority class is ``cls``."""
    out = {}
    for rows in rows_by_id(ids):
        lab = labels[rows]
        lab = lab[(lab >= 0) & (lab < NUM_CLASSES)]
        if lab.size == 0 or rows.size < min_points:
            continue
        if int(np.bincount(lab, minlength=NUM_CLASSES).argmax()) == cls:
            out[int(ids[rows[0]])] = rows
    return out


def f1(tp: int, fp: int, fn: int) -> tuple[float, float, float]:
    """Precision, recall and F1 (1.0 where nothing was there and nothing was found)."""
    precision = tp / (tp + fp) if tp + fp else 1.0
    recall = tp / (tp + fn) if tp + fn else 1.0
    score = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return precision, recall, score
