"""The evidence vote on hand-made arrays: it flips only points the network was unsure about,
towards what their unit believes, never against a confident network, and keeps the network's
labels where the unit does not change a point's decision."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.classes import NUM_CLASSES
from jointseg.fusion import FusionParams, fuse
from jointseg.fusion.evidence import evidence_labels, point_probs
from tests.support.probs import probs_for

EVIDENCE = FusionParams(mode="evidence", vote_cell_size=0.0)


def segment_of_walls(extra: dict[int, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nine confident wall points (class 2) and one point with ``extra`` probabilities."""
    rows = [{2: 0.9, 5: 0.05}] * 9 + [extra]
    probs = probs_for(rows)
    xyz = np.column_stack([np.arange(10) * 0.01, np.zeros(10), np.zeros(10)])
    return xyz, probs, probs.argmax(axis=1)


def test_an_unsure_point_follows_its_segment() -> None:
    xyz, probs, labels = segment_of_walls({5: 0.5, 2: 0.4})  # window, barely
    result = fuse(xyz, np.zeros(10, int), labels, probs, EVIDENCE)
    assert labels[-1] == 5 and result.labels[-1] == 2
    assert (result.labels[:9] == 2).all()


def test_a_confident_point_keeps_its_label_against_its_segment() -> None:
    xyz, probs, labels = segment_of_walls({11: 0.95, 2: 0.03})  # a board inside a wall plane
    result = fuse(xyz, np.zeros(10, int), labels, probs, EVIDENCE)
    assert result.labels[-1] == 11
    # the paper's majority rule overwrites it
    paper = fuse(xyz, np.zeros(10, int), labels, probs, FusionParams(mode="paper"))
    assert paper.labels[-1] == 2


def test_a_stronger_weight_flips_more() -> None:
    xyz, probs, labels = segment_of_walls({11: 0.7, 2: 0.2})
    weak = fuse(xyz, np.zeros(10, int), labels, probs, EVIDENCE)
    strong = fuse(
        xyz, np.zeros(10, int), labels, probs, EVIDENCE.model_copy(update={"evidence_weight": 2.0})
    )
    assert weak.labels[-1] == 11 and strong.labels[-1] == 2


def test_weight_zero_returns_the_network_labels_even_where_they_are_not_the_argmax() -> None:
    rng = np.random.default_rng(0)
    probs = rng.dirichlet(np.ones(NUM_CLASSES), 200).astype(np.float32)
    labels = rng.integers(0, NUM_CLASSES, 200)  # e.g. a K-neighbour majority
    fused, _ = evidence_labels(rng.integers(0, 5, 200), 5, labels, probs, weight=0.0)
    assert np.array_equal(fused, labels)


def test_cells_keep_the_vote_local_in_a_long_segment() -> None:
    # a 4 m wall segment: its left half is wall, its right half a board the network sees as
    # board, unsurely; one unsure point on each side
    n = 400
    x = np.linspace(0, 4, n)
    xyz = np.column_stack([x, np.zeros(n), np.zeros(n)])
    rows = [{2: 0.6, 11: 0.3} if xi < 2 else {11: 0.55, 2: 0.35} for xi in x]
    rows[10] = {11: 0.5, 2: 0.45}  # left, should become wall
    rows[390] = {2: 0.5, 11: 0.45}  # right, should become board
    probs = probs_for(rows)
    labels = probs.argmax(axis=1)
    local = fuse(xyz, np.zeros(n, int), labels, probs, FusionParams(mode="evidence"))
    assert local.labels[10] == 2 and local.labels[390] == 11
    whole = fuse(
        xyz, np.zeros(n, int), labels, probs, EVIDENCE.model_copy(update={"evidence_weight": 2.0})
    )
    # over the whole 4 m the wall half outweighs the board half: the right point stays wall
    assert whole.labels[390] == 2


def test_hard_labels_are_smoothed_one_hot() -> None:
    p = point_probs(np.array([3, 0]), None)
    assert p.shape == (2, NUM_CLASSES)
    assert np.allclose(p.sum(axis=1), 1.0) and p[0].argmax() == 3 and p[1].argmax() == 0


@pytest.mark.parametrize("weight", [-0.1])
def test_negative_weight_is_rejected(weight: float) -> None:
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="evidence_weight"):
        FusionParams(mode="evidence", evidence_weight=weight)
