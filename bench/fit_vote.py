"""Fit the learned vote (jointseg/fusion/vote_model.json) on real tuning rooms and synthetic rooms.

Training samples are the offers of jointseg.fusion.learned.vote_offers (a point's segment label
or, where that differs, its cell label, wherever the network labelled the point otherwise) where
the offer or the network's label is the truth; the target is "the offer is right". Each room
weighs the same, and inside a room an offer weighs by the inverse frequency of its true class
(mIoU counts every class alike). The real tuning rooms are labelled twice, by DGCNN model_6 (a
strong network that never saw Area_6) and by the synthetic-only RandLA-Net (bench/checkpoints,
a weak one), and synthetic calibration rooms (seeds 7000+, never a benchmark's held-out seed) by
that RandLA-Net, so
the rule sees strong and weak networks on impure real segments and a weak one on clean synthetic
segments. The rule is constrained to be monotone in the support of the offer and of the point's
own label (--no-monotonic lifts that). The judging rooms of bench/fusion_real.py are never read;
--cv N prints leave-rooms-out gains over the tuning and synthetic rooms instead of writing a
model, to choose the settings without them.

    .venv/bin/python bench/fit_vote.py --cv 5 --depth 3 --trees 100   # compare settings
    .venv/bin/python bench/fit_vote.py --depth 3 --trees 100   # writes vote_model.json
    .venv/bin/python bench/fusion_real.py ...     # then judge it
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier

from jointseg.fusion.learned import (
    DEFAULT_CELL_SIZE,
    FEATURES,
    MODEL_PATH,
    Offers,
    best_offers,
    vote_offers,
)
from jointseg.fusion.params import FusionParams
from jointseg.metrics import evaluate
from jointseg.synth import make_floor, make_room

sys.path.insert(0, str(Path(__file__).parent))
import fusion_real as fr  # noqa: E402

M6 = f"dgcnn:{fr.SHARED / 'models' / 'dgcnn_s3dis' / 'model_6.t7'}"
#: The weak network the shipped vote model was fitted with: the synthetic-only RandLA-Net that
#: was bundled then (the bundled one now was trained on rooms the vote tunes on).
WEAK = f"randlanet:{Path(__file__).parent / 'checkpoints' / 'randlanet_synth.pt'}"
CALIBRATION_SEED = 7000
#: The rule may only grow more willing to relabel as the offered label gains support (at the
#: point, in the segment, in the cell) and less as the point's own label does: a prior that
#: keeps it sensible on networks whose probabilities look unlike the fitted ones.
MONOTONIC = [
    {
        "logit p(own)": -1,
        "logit segment soft share of own": -1,
        "logit cell soft share of own": -1,
    }.get(name, 1 if "offer" in name and name.startswith("logit") else 0)
    for name in FEATURES
]


def calibration_rooms(rooms: int, floors: int, points: int) -> list[fr.Item]:
    """Synthetic rooms and floors with seeds no benchmark holds out."""
    out = []
    for i in range(rooms):
        shape = "L" if i % 2 else "box"
        name = f"room {CALIBRATION_SEED + i} ({shape})"
        scan = make_room(CALIBRATION_SEED + i, points=points, shape=shape)
        out.append(fr.Item(name, scan, fr.content_key(name, points), "calibration"))
    for i in range(floors):
        name = f"floor {CALIBRATION_SEED + 100 + i}"
        scan = make_floor(CALIBRATION_SEED + 100 + i, points=3 * points)
        out.append(fr.Item(name, scan, fr.content_key(name, points), "calibration"))
    return out


@dataclass
class Room:
    """One room's offers, what is true of them, and what scoring a rule on it needs."""

    name: str
    real: bool
    network: str
    gt: np.ndarray
    labels: np.ndarray
    offers: Offers
    truth: np.ndarray  # ground truth at each offer's point
    weight: np.ndarray  # per offer: inverse frequency of the true class, rooms weigh alike


def load_room(item: fr.Item, spec: str, predictors: dict, min_support: float) -> Room:
    """Offers of one room (segments of the default geometry), with their truth and weights."""
    labels, probs = fr.network_output(spec, item, predictors)
    g = fr.geometry_output("default", item)
    seg = g["segments"].astype(np.int64)
    gt = item.scan.labels
    assert gt is not None
    offers = vote_offers(
        item.scan.xyz,
        seg,
        int(seg.max()) + 1,
        labels,
        probs,
        cell_size=DEFAULT_CELL_SIZE,
        main_plane=g["plane_id"] >= 0,
        min_support=min_support,
    )
    truth = gt[offers.point]
    freq = np.bincount(gt[gt >= 0], minlength=13) / max(int((gt >= 0).sum()), 1)
    w = 1.0 / (freq[np.maximum(truth, 0)] + 0.02)
    useful = (truth == offers.label) | (truth == labels[offers.point])
    w = np.where(useful, w, 0.0)
    return Room(
        item.name, item.split == "tune", spec, gt, labels, offers, truth, w / max(w.sum(), 1e-12)
    )


def fused_labels(room: Room, p: np.ndarray, threshold: float) -> np.ndarray:
    """The room's labels after taking each point's most probable offer above ``threshold``."""
    return best_offers(room.labels, room.offers.point, room.offers.label, p, threshold)


def fit(rooms: list[Room], args: argparse.Namespace) -> HistGradientBoostingClassifier:
    x = np.concatenate([r.offers.features for r in rooms])
    y = np.concatenate([r.truth == r.offers.label for r in rooms])
    w = np.concatenate([r.weight for r in rooms]) * len(rooms)
    use = w > 0
    return HistGradientBoostingClassifier(
        max_depth=args.depth,
        max_iter=args.trees,
        min_samples_leaf=args.min_leaf,
        l2_regularization=args.l2,
        learning_rate=args.learning_rate,
        monotonic_cst=MONOTONIC if args.monotonic else None,
        random_state=0,
    ).fit(x[use], y[use], sample_weight=w[use])


def gains(clf: HistGradientBoostingClassifier, rooms: list[Room], threshold: float) -> np.ndarray:
    """mIoU gain (points) of the rule on each room."""
    out = []
    for r in rooms:
        p = clf.predict_proba(r.offers.features)[:, 1] if len(r.truth) else np.zeros(0)
        net = evaluate(r.gt, r.labels).miou or 0.0
        out.append(100 * ((evaluate(r.gt, fused_labels(r, p, threshold)).miou or 0.0) - net))
    return np.array(out)


def cross_validate(rooms: list[Room], args: argparse.Namespace, folds: int) -> None:
    """Leave-rooms-out gains on the tuning and synthetic rooms (the judging rooms stay unread);
    a room labelled by several networks stays in one fold."""
    names = sorted({r.name for r in rooms})
    fold_of = {name: i % folds for i, name in enumerate(names)}
    found: dict[str, list[float]] = {}
    for k in range(folds):
        test = [r for r in rooms if fold_of[r.name] == k]
        clf = fit([r for r in rooms if fold_of[r.name] != k], args)
        for r, g in zip(test, gains(clf, test, args.threshold), strict=True):
            found.setdefault(r.network if r.real else "synthetic", []).append(float(g))
    cells = []
    for key, values in found.items():
        a = np.array(values)
        name = key.rpartition("/")[2]
        cells.append(f"{name} {a.mean():+.2f} / {a.min():+.2f} lost {(a < -0.5).sum()}")
    print(
        f"cv depth {args.depth} trees {args.trees} leaf {args.min_leaf} l2 {args.l2} "
        f"lr {args.learning_rate} t {args.threshold}: " + "; ".join(cells)
    )


def export(clf: HistGradientBoostingClassifier) -> dict:
    """The fitted ensemble as plain arrays (see jointseg.fusion.learned.TreeEnsemble)."""
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--judge", type=int, default=10, help="real judging rooms left out")
    parser.add_argument("--synth-rooms", type=int, default=10)
    parser.add_argument("--synth-floors", type=int, default=2)
    parser.add_argument("--synth-points", type=int, default=100_000)
    parser.add_argument(
        "--real-network",
        action="append",
        help="networks that label the real tuning rooms; repeat (default DGCNN model_6 and the "
        "synthetic-only RandLA-Net: a strong and a weak network on the same impure real segments)",
    )
    parser.add_argument("--trees", type=int, default=50)
    parser.add_argument("--depth", type=int, default=2)
    parser.add_argument("--min-leaf", type=int, default=200, help="least samples per leaf")
    parser.add_argument("--l2", type=float, default=1.0, help="L2 regularisation of leaves")
    parser.add_argument("--learning-rate", type=float, default=0.1)
    parser.add_argument("--threshold", type=float, default=FusionParams().flip_threshold)
    parser.add_argument(
        "--monotonic",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="constrain the rule to be monotone in the support of the offer and own label",
    )
    parser.add_argument("--cv", type=int, default=0, help="only cross-validate, in this many folds")
    parser.add_argument("--out", type=Path, default=MODEL_PATH)
    args = parser.parse_args()
    args.real_network = args.real_network or [M6, WEAK]
    logging.basicConfig(level=logging.WARNING)
    real = [i for i in fr.load_items([str(fr.AREA6)], args.judge, (0, 0, 0)) if i.split == "tune"]
    synth = calibration_rooms(args.synth_rooms, args.synth_floors, args.synth_points)
    predictors: dict = {}
    support = FusionParams().min_support
    rooms = [load_room(i, spec, predictors, support) for spec in args.real_network for i in real]
    rooms += [load_room(i, WEAK, predictors, support) for i in synth]
    if args.cv:
        cross_validate(rooms, args, args.cv)
        return
    t = time.perf_counter()
    clf = fit(rooms, args)
    body = {
        "features": list(FEATURES),
        "cell_size": DEFAULT_CELL_SIZE,
        **export(clf),
        "card": {
            "what": "P(a label offered by a point's segment or cell is right where the network "
            "disagrees)",
            "trained_on": {
                "real": [i.name for i in real],
                "real_networks": [n.rpartition("/")[2] for n in args.real_network],
                "synthetic": [i.name for i in synth],
                "synthetic_network": "synthetic-only RandLA-Net (bench/checkpoints)",
                "synthetic_points": args.synth_points,
                "geometry": "GeometryParams() defaults",
            },
            "samples": int(sum(int((r.weight > 0).sum()) for r in rooms)),
            "trees": args.trees,
            "max_depth": args.depth,
            "min_samples_leaf": args.min_leaf,
            "l2_regularization": args.l2,
            "learning_rate": args.learning_rate,
            "monotonic": args.monotonic,
            "command": "bench/fit_vote.py " + " ".join(sys.argv[1:]),
            "date": time.strftime("%F"),
            "data_terms": "real rooms are derived from S3DIS (Stanford; research use, cite "
            "Armeni et al. 2016); the model stores only split thresholds and leaf values",
        },
    }
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(body, separators=(",", ":")))
    tmp.replace(args.out)
    print(
        f"{body['card']['samples']} samples from {len(real)} real and {len(synth)} synthetic "
        f"rooms, fitted in {time.perf_counter() - t:.1f} s -> {args.out} "
        f"({args.out.stat().st_size} bytes)"
    )


if __name__ == "__main__":
    main()
