"""The learned vote made fast gives what the plain vote gives, to the bit: the tree ensemble
against a walk of every tree for every row (and scikit-learn's own prediction), the class
columns' sums and entropy against the row-major ones, the door pieces, the best offer per
point, and the whole vote against :mod:`tests.fusion.plain_vote`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX, NUM_CLASSES
from jointseg.fusion import FusionParams, StructureHint, fixtures, fuse, trees
from jointseg.fusion import offers as offers_module
from jointseg.fusion.columns import ClassColumns, rows_entropy
from jointseg.fusion.columns import _pairwise_matches_numpy as pairwise_matches_numpy
from jointseg.fusion.guard import aligned_cell_keys, segment_cells
from jointseg.fusion.learned import best_offers, learned_labels
from jointseg.fusion.offers import FEATURES, POINT_FEATURES, normalised_entropy, vote_offers
from jointseg.fusion.thresholds import ClassTally
from jointseg.fusion.tree_runtime import TreeEnsemble, shipped_model
from jointseg.grouping import cell_keys, compact_ids, group_sums
from jointseg.synth import make_room
from jointseg.synth.label_noise import corrupt_labels
from tests.fusion import plain_vote

WALL, DOOR = CLASS_INDEX["wall"], CLASS_INDEX["door"]


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Equal values, NaN where NaN, and the same sign of every zero."""
    return bool(
        np.array_equal(a, b, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(b))
    )


def random_tree(rng: np.random.Generator, n_features: int, depth: int, cuts: np.ndarray) -> dict:
    """A random binary tree at most ``depth`` deep, its thresholds drawn from ``cuts``."""
    tree: dict[str, list] = {k: [] for k in ("feature", "threshold", "left", "right", "value")}
    tree["leaf"] = []

    def grow(level: int) -> int:
        node = len(tree["leaf"])
        for k in tree:
            tree[k].append(0)
        if level == depth or (level > 1 and rng.random() < 0.2):
            tree["leaf"][node] = True
            tree["value"][node] = float(rng.normal())
            return node
        tree["leaf"][node] = False
        tree["feature"][node] = int(rng.integers(n_features))
        tree["threshold"][node] = float(rng.choice(cuts))
        tree["left"][node] = grow(level + 1)
        tree["right"][node] = grow(level + 1)
        return node

    grow(0)
    return tree


def random_model(path: Path, seed: int, n_trees: int = 30) -> TreeEnsemble:
    """Trees 1 to 6 deep (some with more split nodes than a table holds) over every feature."""
    rng = np.random.default_rng(seed)
    cuts = np.round(rng.normal(size=40), 1)
    body = {
        "features": list(FEATURES),
        "base": float(rng.normal()),
        "trees": [
            random_tree(rng, len(FEATURES), int(rng.integers(1, 7)), cuts) for _ in range(n_trees)
        ],
    }
    path.write_text(json.dumps(body))
    return TreeEnsemble.from_json(path)


def rows_with_contexts(rng: np.random.Generator, m: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows (m, F) of k contexts: equal features within a context except the point features,
    values often exactly on a threshold, some constant columns, some NaN."""
    table = np.round(rng.normal(size=(k, len(FEATURES))), 1)
    table[rng.random(table.shape) < 0.02] = np.nan
    table[:, FEATURES.index("scan mean entropy")] = 0.3
    table[:, FEATURES.index("scan has colour")] = 1.0
    context = rng.integers(0, k, m) * 7 + 3  # any integers
    x = table[context // 7]
    for f in POINT_FEATURES:
        x[:, f] = np.round(rng.normal(size=m), int(rng.integers(1, 3)))
        x[rng.random(m) < 0.01, f] = np.nan
    return x, context


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_ensemble_scores_every_row_as_a_walk_of_every_tree(tmp_path: Path, seed: int) -> None:
    model = random_model(tmp_path / "m.json", seed)
    assert any((~leaf).sum() > 2 * trees.MAX_TABLE_BITS for leaf in model.leaf)  # walked ones
    x, context = rows_with_contexts(np.random.default_rng(seed), 3000, 40)
    expected = plain_vote.walk(model, x)
    assert same_bits(model.decision(x), expected)
    assert same_bits(model.decision(x, context), expected)
    assert same_bits(model.decision(np.asfortranarray(x), context), expected)
    np.testing.assert_array_equal(model.probability(x, context), 1 / (1 + np.exp(-expected)))


def test_the_shipped_model_scores_every_row_as_a_walk_of_every_tree() -> None:
    model = shipped_model()
    x, context = rows_with_contexts(np.random.default_rng(5), 2000, 30)
    x = np.nan_to_num(x)
    expected = plain_vote.walk(model, x)
    assert same_bits(model.decision(x), expected)
    assert same_bits(model.decision(x, context), expected)


def test_an_ensemble_of_deep_trees_or_no_trees_is_scored(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    cuts = np.linspace(-1, 1, 9)
    deep = [random_tree(rng, 3, 7, cuts) for _ in range(3)]
    path = tmp_path / "deep.json"
    path.write_text(json.dumps({"features": list(FEATURES), "base": 0.25, "trees": deep}))
    model = TreeEnsemble.from_json(path)
    x = np.round(rng.normal(size=(500, len(FEATURES))), 1)
    assert same_bits(model.decision(x), plain_vote.walk(model, x))
    path.write_text(json.dumps({"features": list(FEATURES), "base": 0.25, "trees": []}))
    empty = TreeEnsemble.from_json(path)
    np.testing.assert_array_equal(empty.decision(x, np.zeros(500, np.int64)), 0.25)
    assert empty.decision(x[:0]).shape == (0,)


def test_the_ensemble_agrees_with_scikit_learns_prediction(tmp_path: Path) -> None:
    ensemble = pytest.importorskip("sklearn.ensemble")
    from jointseg.fitting.vote_trees import export

    rng = np.random.default_rng(4)
    x, context = rows_with_contexts(rng, 4000, 60)
    x = np.nan_to_num(x)
    y = (x[:, 0] + x[:, 2] * x[:, 7] + rng.normal(0, 0.5, len(x)) > 0).astype(int)
    clf = ensemble.HistGradientBoostingClassifier(max_iter=25, max_leaf_nodes=40, random_state=0)
    clf.fit(x, y)
    path = tmp_path / "sk.json"
    path.write_text(json.dumps({"features": list(FEATURES), **export(clf)}))
    model = TreeEnsemble.from_json(path)
    assert any((~leaf).sum() > trees.MAX_TABLE_BITS for leaf in model.leaf)
    np.testing.assert_array_equal(model.decision(x, context), clf.decision_function(x))
    np.testing.assert_allclose(model.probability(x), clf.predict_proba(x)[:, 1], rtol=1e-12)


def test_an_old_model_without_the_structure_features_is_scored(tmp_path: Path) -> None:
    rng = np.random.default_rng(6)
    cuts = np.round(rng.normal(size=20), 1)
    n = len(FEATURES) - 5
    body = {
        "features": list(FEATURES[:n]),
        "base": 0.1,
        "trees": [random_tree(rng, n, 4, cuts) for _ in range(10)],
    }
    path = tmp_path / "old.json"
    path.write_text(json.dumps(body))
    model = TreeEnsemble.from_json(path)
    x, context = rows_with_contexts(rng, 1000, 20)
    assert same_bits(model.decision(x, context), plain_vote.walk(model, x))


@pytest.mark.parametrize("n_classes", [3, 8, 13, 20])
@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
def test_class_columns_sum_and_take_entropies_as_the_rows_do(n_classes: int, dtype: type) -> None:
    rng = np.random.default_rng(n_classes)
    probs: np.ndarray = rng.dirichlet(np.full(n_classes, 0.3), 30_000).astype(dtype)
    probs[:, 1] = 0  # a class ruled out for the scan
    probs[:9000, 2] = 0  # and for a block of points
    probs[7, 2:] = -0.0  # -0.0 is not ruled out
    probs[8] = 0
    unit = rng.integers(0, 60, len(probs))
    columns = ClassColumns.of(probs)
    assert pairwise_matches_numpy(n_classes)  # the fast row sum is the one taken
    assert not columns.live[1] and columns.live[2]
    np.testing.assert_array_equal(columns.sums(unit, 64), group_sums(unit, 64, probs))
    expected = plain_vote.entropy(probs)
    assert same_bits(columns.entropy(), expected)
    assert same_bits(rows_entropy(probs), expected)
    assert same_bits(normalised_entropy(probs), expected)


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
def test_the_class_tally_is_the_row_major_one(dtype: type) -> None:
    rng = np.random.default_rng(7)
    probs = rng.dirichlet(np.full(NUM_CLASSES, 0.5), 540_000).astype(dtype)
    probs[:, 3] = 0
    labels = rng.integers(0, NUM_CLASSES, len(probs))
    fast, plain = ClassTally.of(labels, probs), plain_vote.tally(labels, probs)
    for name in ("counts", "expected", "agreed"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(plain, name))


def test_cells_and_door_pieces_are_found_as_before() -> None:
    rng = np.random.default_rng(8)
    xyz = rng.uniform(-3, 5, (20_000, 3))
    seg = rng.integers(0, 30, len(xyz))
    keys, n_keys = cell_keys(xyz, 0.3, aligned=True)
    fast_keys, fast_n = aligned_cell_keys(xyz, 0.3)
    np.testing.assert_array_equal(fast_keys, keys)
    assert fast_n == n_keys
    unit, n_units = segment_cells(xyz, seg, 0.3)
    plain_unit, plain_n = plain_vote.segment_cells(xyz, seg, 0.3)
    np.testing.assert_array_equal(unit, plain_unit)
    assert n_units == plain_n
    clustered = np.round(xyz[:3000] * 3) / 3  # touching and separate cells
    piece, n = fixtures._pieces(clustered)
    plain_piece, plain_n = plain_vote.pieces(clustered)
    np.testing.assert_array_equal(piece, plain_piece)
    assert n == plain_n


def test_the_best_offer_per_point_is_the_most_probable_first_one() -> None:
    rng = np.random.default_rng(9)
    labels = rng.integers(0, NUM_CLASSES, 5000)
    point = np.concatenate([rng.permutation(5000)[:3000], rng.permutation(5000)[:2500]])
    label = rng.integers(0, NUM_CLASSES, len(point))
    p = np.round(rng.random(len(point)), 2)  # ties
    at = rng.uniform(0.3, 0.7, len(point))
    np.testing.assert_array_equal(
        best_offers(labels, point, label, p, at), plain_vote.best(labels, point, label, p, at)
    )
    np.testing.assert_array_equal(best_offers(labels, point, label, p, 2.0), labels)


def room_inputs(seed: int, points: int, dead: bool) -> dict:
    """A labelled synthetic room as the vote gets it: a stand-in network's labels and
    probabilities (some classes ruled out where ``dead``), segments of its objects cut into
    blocks, main planes, a structure reading, and a wall stretch the network calls door."""
    room = make_room(seed, points=points)
    assert room.labels is not None
    rng = np.random.default_rng(seed)
    labels, probs = corrupt_labels(room.xyz, room.labels, rng=rng)
    if dead:
        probs[:, [CLASS_INDEX["sofa"], CLASS_INDEX["beam"]]] = 0
    x = room.xyz[:, 0]
    stretch = (room.labels == WALL) & (x < np.quantile(x[room.labels == WALL], 0.3))
    probs[stretch, DOOR] += 1.0
    probs /= probs.sum(axis=1, keepdims=True)
    labels = probs.argmax(axis=1)
    blocks, _ = cell_keys(room.xyz, 1.5)
    _, seg = compact_ids(blocks * NUM_CLASSES + room.labels)
    structural = np.isin(room.labels, [CLASS_INDEX[c] for c in ("ceiling", "floor", "wall")])
    read = structural & (rng.random(int(seg.max()) + 1) < 0.8)[seg]
    kind = np.where(read, room.labels, -1)
    sure = np.where(read, rng.uniform(0.4, 1.0, int(seg.max()) + 1)[seg], 0.0)
    return {
        "xyz": room.xyz,
        "seg": seg,
        "labels": labels,
        "probs": probs.astype(np.float32),
        "main_plane": structural & (rng.random(len(seg)) < 0.9),
        "structure": StructureHint(kind, sure),
    }


@pytest.mark.parametrize(
    ("seed", "dead", "structure", "metric_iou", "workers"),
    [(0, False, True, "auto", 1), (1, True, True, "auto", 0), (2, False, False, 0.6, 1)],
)
def test_the_fast_vote_is_the_plain_vote(
    monkeypatch: pytest.MonkeyPatch,
    seed: int,
    dead: bool,
    structure: bool,
    metric_iou: float | str,
    workers: int,
) -> None:
    monkeypatch.setattr(offers_module, "WORKERS", workers)
    given = room_inputs(seed, 25_000, dead)
    hint = given["structure"] if structure else None
    n_seg = int(given["seg"].max()) + 1
    model = shipped_model()
    args = (given["xyz"], given["seg"], n_seg, given["labels"], given["probs"])
    options = {"main_plane": given["main_plane"], "structure": hint, "has_colour": True}
    plain_point, plain_offer, plain_features, plain_votes = plain_vote.offer_features(
        *args, cell_size=model.cell_size, min_support=0.03, **options
    )
    offers = vote_offers(*args, cell_size=model.cell_size, min_support=0.03, **options)
    np.testing.assert_array_equal(offers.point, plain_point)
    np.testing.assert_array_equal(offers.label, plain_offer)
    assert same_bits(offers.features, plain_features)
    np.testing.assert_array_equal(offers.segment_votes, plain_votes)
    assert (offers.features[:, FEATURES.index("own label is a wall fixture")] == 1).any()
    # the context's promise: offers of one context differ in the point features only
    assert offers.context is not None
    _, ctx = compact_ids(offers.context)
    others = [f for f in range(len(FEATURES)) if f not in POINT_FEATURES]
    first = np.zeros(int(ctx.max()) + 1, dtype=np.int64)
    first[ctx[::-1]] = np.arange(len(ctx))[::-1]
    assert same_bits(offers.features[:, others], offers.features[first[ctx]][:, others])
    vote = {"threshold": 0.55, "min_support": 0.03, "metric_iou": metric_iou}
    vote |= {"seen_fixture_share": 0.7, **options}
    fused, votes = learned_labels(*args, **vote)
    plain_fused, _ = plain_vote.learned_labels(model, *args, **vote)
    np.testing.assert_array_equal(fused, plain_fused)
    np.testing.assert_array_equal(votes, plain_votes)
    assert (fused != given["labels"]).any()


def test_a_failure_beside_the_vote_reaches_the_caller(monkeypatch: pytest.MonkeyPatch) -> None:
    given = room_inputs(5, 5000, False)

    def broken(*args: object, **kwargs: object) -> np.ndarray:
        raise RuntimeError("door sizes failed")

    monkeypatch.setattr(offers_module, "implausible_doors", broken)
    for workers in (0, 1):
        monkeypatch.setattr(offers_module, "WORKERS", workers)
        with pytest.raises(RuntimeError, match="door sizes failed"):
            fuse(given["xyz"], given["seg"], given["labels"], given["probs"])


def test_fusing_the_same_scan_twice_gives_the_same_bits() -> None:
    given = room_inputs(4, 15_000, True)
    params = FusionParams(mode="learned")
    run = [
        fuse(
            given["xyz"],
            given["seg"],
            given["labels"],
            given["probs"],
            params,
            main_plane=given["main_plane"],
            structure=given["structure"],
        )
        for _ in range(2)
    ]
    np.testing.assert_array_equal(run[0].labels, run[1].labels)
    np.testing.assert_array_equal(run[0].confidence, run[1].confidence)
