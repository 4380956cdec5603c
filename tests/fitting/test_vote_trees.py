"""The vote's trees as the package fits and exports them (issue 69, point 4): the numpy runtime
that reads the exported file gives scikit-learn's own ``predict_proba``.

Why: the export reads scikit-learn's private attributes (``_predictors``, the nodes' fields,
``_baseline_prediction``); a scikit-learn that stores them otherwise must fail here, not ship a
vote that silently decides differently."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.fitting.vote import Room, TreeParams
from jointseg.fitting.vote_trees import export, fit_trees, rounded
from jointseg.fusion.offers import FEATURES, POINT_FEATURES, Offers
from jointseg.fusion.thresholds import ClassTally
from jointseg.fusion.tree_runtime import TreeEnsemble

pytest.importorskip("sklearn.ensemble")


def random_room(rng: np.random.Generator, name: str, dataset: str, n: int) -> Room:
    """A room of ``n`` offers with random features (a few columns binary, one constant) whose
    rightness depends on some of them, as the fit reads a labelled scan."""
    x = rng.normal(size=(n, len(FEATURES)))
    x[:, FEATURES.index("own label is structural")] = rng.integers(0, 2, n)
    x[:, FEATURES.index("offer is the segment's label")] = rng.integers(0, 2, n)
    x[:, FEATURES.index("scan has colour")] = 1.0
    score = x[:, 1] - x[:, 0] + 0.8 * x[:, 2] * x[:, 13] + rng.normal(0, 0.7, n)
    label = rng.integers(0, 13, n)
    truth = np.where(score > 0, label, (label + 1) % 13)
    point = np.arange(n, dtype=np.int64)
    offers = Offers(point, label, x, label, np.zeros((1, 13)))
    weight = rng.uniform(0.5, 1.5, n)
    empty = np.zeros(0, dtype=np.int64)
    return Room(
        name, dataset, name, "random", empty, empty, offers, truth, weight / weight.sum(),
        ClassTally.empty(),
    )  # fmt: skip


def test_the_exported_trees_give_scikit_learns_probabilities(tmp_path: Path) -> None:
    rng = np.random.default_rng(69)
    rooms = [random_room(rng, f"room {i}", "ab"[i % 2], 3000) for i in range(4)]
    params = TreeParams(trees=30, depth=4, min_leaf=20, monotonic=True)
    clf = fit_trees(rooms, params, {"a": 1.0, "b": 2.0})
    path = tmp_path / "vote.json"
    path.write_text(json.dumps({"features": list(FEATURES), **export(clf)}))
    model = TreeEnsemble.from_json(path)
    assert len(model.feature) == params.trees
    assert sum(int((~leaf).sum()) for leaf in model.leaf) > params.trees  # not stumps only
    held_out = rounded(random_room(rng, "held out", "a", 5000).offers.features)
    expected = clf.predict_proba(held_out)[:, 1]
    assert 0.05 < expected.mean() < 0.95 and expected.std() > 0.05  # the trees decide something
    np.testing.assert_allclose(model.probability(held_out), expected, rtol=0, atol=1e-6)
    # the grouped evaluation the vote uses: rows of one context differ in the point features only
    context = np.arange(len(held_out)) % 7
    shared = [f for f in range(len(FEATURES)) if f not in POINT_FEATURES]
    grouped = held_out.copy()
    grouped[:, shared] = held_out[context][:, shared]
    np.testing.assert_allclose(
        model.probability(grouped, context), clf.predict_proba(grouped)[:, 1], rtol=0, atol=1e-6
    )
