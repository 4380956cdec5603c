"""Corrections made a whole segment at a time carry the points of other objects the segment
held; the head learns from the corrected points whose class the bundled network finds
possible, and from every point of a class it misses altogether."""

from __future__ import annotations

import numpy as np

from jointseg.adapt.head import AdaptParams, Examples
from jointseg.classes import NUM_CLASSES


def _teacher(rows: list[tuple[int, float]]) -> np.ndarray:
    """Probabilities with ``p`` on class ``c`` per row, the rest spread evenly."""
    out = np.empty((len(rows), NUM_CLASSES))
    for i, (c, p) in enumerate(rows):
        out[i] = (1 - p) / (NUM_CLASSES - 1)
        out[i, c] = p
    return out


def test_a_point_of_another_object_in_a_corrected_segment_is_not_learnt() -> None:
    # four table points the network half believes, one clutter point it gives table 1e-5
    # (it is sure that one is clutter), and an uncorrected point
    teacher = _teacher([(7, 0.5)] * 4 + [(12, 1 - 1e-5)] + [(2, 0.9)])
    teacher[4, 7] = 1e-5
    target = np.array([7, 7, 7, 7, 7, -1])
    ex = Examples(np.zeros((6, 4), np.float32), target, teacher)
    keep = ex.believable(AdaptParams().min_base_probability)
    assert keep.tolist() == [True, True, True, True, False, False]
    assert ex.believable(0.0).tolist() == [True] * 5 + [False]


def test_every_point_of_a_class_the_network_misses_is_learnt() -> None:
    # the user names beams the network never gives more than 1e-5: nothing tells a beam
    # point from another object's, so every corrected beam point counts
    teacher = _teacher([(2, 0.99)] * 3)
    teacher[:, 3] = 1e-5
    ex = Examples(np.zeros((3, 4), np.float32), np.array([3, 3, 3]), teacher)
    assert ex.believable(AdaptParams().min_base_probability).all()


def test_a_segment_the_network_gets_wrong_whole_is_learnt_whole() -> None:
    # segment 0: a table the network calls clutter at every point (what a correction fixes);
    # segment 1: a table with one chair point in it
    teacher = _teacher([(12, 1 - 1e-5)] * 3 + [(7, 0.6)] * 5 + [(8, 1 - 1e-5)])
    teacher[:3, 7] = teacher[8, 7] = 1e-5
    target = np.full(9, 7)
    group = np.array([0, 0, 0, 1, 1, 1, 1, 1, 1])
    ex = Examples(np.zeros((9, 4), np.float32), target, teacher, group)
    assert ex.believable(AdaptParams().min_base_probability).tolist() == [True] * 8 + [False]
    # without the segments, the three wrong-whole points would be a minority of the class
    alone = Examples(ex.features, target, teacher)
    assert alone.believable(AdaptParams().min_base_probability).tolist() == (
        [False] * 3 + [True] * 5 + [False]
    )
