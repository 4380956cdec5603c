"""The learned vote's trees fitted on the offers of :mod:`jointseg.fitting.vote`, and the model
file they are written as.

Why these choices: scikit-learn's histogram gradient boosting with a fixed seed, on one OpenMP
thread (sums taken in another order could move a split), over samples in the plan's order, so
the same offers give the same trees; the file holds no date or path (those are in the
provenance beside it), so the same trees give the same bytes.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.fitting.provenance import Provenance, fit_record, write_model
from jointseg.fitting.vote import (
    BIAS,
    LOST,
    LOST_CELL,
    LOST_SHARE,
    Loaded,
    Room,
    Sources,
    TreeParams,
    VotePlan,
    load_rooms,
)
from jointseg.fusion.offers import FEATURES

#: OpenMP threads the trees are fitted on: one, so that no sum depends on the machine.
FIT_THREADS = 1
#: Decimals the offers' features are rounded to before the trees see them. A split's threshold
#: lies halfway between two feature values, so a last-bit difference in one of them (a float64
#: logarithm or sum taken on another SIMD path, with or without AVX-512) would move it and
#: change the file; rounded, the values are the same on every machine.
FEATURE_DECIMALS = 9
#: What the model's probability means (the card's first line).
WHAT = "P(a label offered by a point's segment or cell is right where the network disagrees)"

#: The rule may only grow more willing to relabel as the offered label gains support (at the
#: point, in the segment, in the cell) and less as the point's own label does: a prior that
#: keeps it sensible on networks whose probabilities look unlike the fitted ones.
MONOTONIC = [
    {
        "logit p(own)": -1,
        "logit segment soft share of own": -1,
        "logit cell soft share of own": -1,
        "structure reads the offer": 1,
        "structure reads own": -1,
    }.get(name, 1 if "offer" in name and name.startswith("logit") else 0)
    for name in FEATURES
]


def rounded(x: np.ndarray) -> np.ndarray:
    """Offer features as the trees see them: rounded to :data:`FEATURE_DECIMALS` (a copy)."""
    return np.round(x, FEATURE_DECIMALS)


def features(room: Room, drop: list[str]) -> np.ndarray:
    """The room's offer features as the trees see them (:func:`rounded`), with the ``drop``
    columns held constant (unusable)."""
    x = rounded(room.offers.features)
    if drop:
        x[:, [FEATURES.index(name) for name in drop]] = 0.0
    return x


def _sklearn() -> Any:
    """scikit-learn's classifier and thread limiter, or a ConfigError saying how to get them."""
    try:
        from sklearn.ensemble import HistGradientBoostingClassifier
        from threadpoolctl import threadpool_limits
    except ImportError as exc:
        raise ConfigError(
            "fitting the vote needs scikit-learn: pip install 'jointseg[fit]'"
        ) from exc
    return HistGradientBoostingClassifier, threadpool_limits


def fit_trees(rooms: list[Room], params: TreeParams, weights: dict[str, float]) -> Any:
    """The rule fitted on ``rooms``: every dataset weighs the same times its weight in
    ``weights``, inside one every labelled scan alike."""
    if not rooms:
        raise ConfigError("no labelled scans to fit the vote on")
    classifier, threadpool_limits = _sklearn()
    per_dataset: dict[str, int] = {}
    for r in rooms:
        per_dataset[r.dataset] = per_dataset.get(r.dataset, 0) + 1
    x = np.concatenate([features(r, params.drop_features) for r in rooms])
    y = np.concatenate([r.truth == r.offers.label for r in rooms])
    w = np.concatenate(
        [r.weight * weights.get(r.dataset, 1.0) / per_dataset[r.dataset] for r in rooms]
    ) * len(rooms)
    use = w > 0
    if not use.any() or len(np.unique(y[use])) < 2:
        raise ConfigError(
            "the tuning scans give no offers to learn from (the networks agree with their "
            "segments everywhere, or every offer is right or every one wrong)"
        )
    model = classifier(
        max_depth=params.depth,
        max_iter=params.trees,
        min_samples_leaf=params.min_leaf,
        l2_regularization=params.l2,
        learning_rate=params.learning_rate,
        monotonic_cst=MONOTONIC if params.monotonic else None,
        random_state=0,
    )
    with threadpool_limits(limits=FIT_THREADS, user_api="openmp"):
        return model.fit(x[use], y[use], sample_weight=w[use])


def export(clf: Any) -> dict[str, Any]:
    """The fitted ensemble as plain arrays (see jointseg.fusion.tree_runtime.TreeEnsemble)."""
    trees = []
    for (predictor,) in clf._predictors:
        nodes = predictor.nodes
        trees.append(
            {
                "feature": nodes["feature_idx"].tolist(),
                "threshold": nodes["num_threshold"].tolist(),
                "left": nodes["left"].tolist(),
                "right": nodes["right"].tolist(),
                "value": nodes["value"].tolist(),
                "leaf": nodes["is_leaf"].astype(bool).tolist(),
            }
        )
    return {"base": float(np.ravel(clf._baseline_prediction)[0]), "trees": trees}


def card(plan: VotePlan, loaded: Loaded) -> dict[str, Any]:
    """What the model says of itself: what it predicts, what it was fitted on and how."""
    p = plan.fit
    weights = {d.name: d.weight for d in plan.datasets}
    names = {r.labeller for r in loaded.rooms}
    return {
        "what": WHAT,
        "trained_on": {
            "scans": {
                d.name: sorted({s.name for s in loaded.scans if s.dataset == d.name})
                for d in plan.datasets
            },
            "labellers": {
                d.name: sorted({r.labeller for r in loaded.rooms if r.dataset == d.name})
                for d in plan.datasets
            },
            "distortions": f"biased: 60 % of a class's probability moved to a confused class "
            f"for {list(BIAS)}; over/underconfident: temperature 0.5 / 2; lost: "
            f"{LOST_SHARE:.0%} of a structural class's probability moved to a confused class "
            f"drawn per {LOST_CELL:g} m plan cell from {LOST}"
            if any("+" in n for n in names)
            else "none",
            "geometry": "GeometryParams() defaults",
            "weighting": f"every dataset alike, times its weight {weights}; inside one every "
            "labelled scan alike; inside a scan offers by inverse true-class frequency",
        },
        "samples": int(sum(int((r.weight > 0).sum()) for r in loaded.rooms)),
        "trees": p.trees,
        "max_depth": p.depth,
        "min_samples_leaf": p.min_leaf,
        "l2_regularization": p.l2,
        "learning_rate": p.learning_rate,
        "monotonic": p.monotonic,
        "dropped_features": list(p.drop_features),
        "data_terms": plan.data_terms,
    }


def fit_vote(
    plan: VotePlan, base: Path, out: Path, *, command: str, cache: Path | None = None
) -> Provenance:
    """Fit the vote the plan describes (scan paths relative to ``base``) and write the model at
    ``out`` and its provenance beside it; returns the provenance written."""
    started = time.perf_counter()
    loaded = load_rooms(plan, base, Sources({}, cache))
    clf = fit_trees(loaded.rooms, plan.fit, {d.name: d.weight for d in plan.datasets})
    body = {
        "features": list(FEATURES),
        "cell_size": plan.cell_size,
        **export(clf),
        "card": card(plan, loaded),
    }
    facts = {
        "samples": body["card"]["samples"],
        "scans x labellers": len(loaded.rooms),
        "openmp_threads": FIT_THREADS,
        "seconds": round(time.perf_counter() - started, 1),
    }
    record = fit_record(plan, command, loaded.scan_records, loaded.labellers, facts)
    return write_model(out, body, record)
