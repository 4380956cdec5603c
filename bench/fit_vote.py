"""Fit the learned vote (jointseg/fusion/vote_model.json) across datasets and networks.

Training samples are the offers of jointseg.fusion.learned.vote_offers (a point's segment label
or, where that differs, its cell label, wherever the network labelled the point otherwise) where
the offer or the network's label is the truth; the target is "the offer is right". The tuning
scans of three datasets are used: S3DIS Area_6 and ScanNet rooms (bench/fusion_real.py's
judging rooms are never read) and synthetic calibration rooms (seeds 7000+, never a benchmark's
held-out seed). Each is labelled by several labellers (LABELLERS): strong and weak networks,
networks that saw the rooms and ones that did not, and deliberately distorted probabilities
(biased towards typical confusions, over- and under-confident), so the rule meets the networks
users bring on the segments other sensors give. Every dataset weighs the same, inside one every
labelled scan, and inside a scan an offer weighs by the inverse frequency of its true class
(mIoU counts every class alike). The rule is constrained to be monotone in the support of the
offer and of the point's own label (--no-monotonic lifts that).

--cv N prints held-out gains per dataset x labeller at each --thresholds value, rooms left out
in N folds (all scans of a room in one); --cv-datasets leaves a whole dataset out at a time.

    .venv/bin/python bench/fit_vote.py --cv 5 --depth 3 --trees 100 --thresholds 0.5 0.6 0.7
    .venv/bin/python bench/fit_vote.py --cv-datasets --depth 3 --trees 100
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
from helpers.inputs import AREA6, M6, MODELS, SCANNET, WEAK
from helpers.scans import (
    THIN,
    Item,
    calibration_rooms,
    colourless,
    content_key,
    geometry_output,
    load_items,
    network_name,
    network_output,
    structure_hint,
    thinned,
)
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
from jointseg.network.randlanet.backend import COLOUR_FREE_WEIGHTS
from jointseg.network.training.data import stable_order
from jointseg.scan import Scan

log = logging.getLogger("fit_vote")

M1 = f"dgcnn:{MODELS / 'dgcnn_s3dis' / 'model_1.t7'}"
GPU = f"randlanet:{MODELS / 'randlanet_area6_gpu' / 'randlanet_area6_gpu.pt'}"
NOCOLOUR = f"randlanet:{COLOUR_FREE_WEIGHTS}"
BUNDLED = "randlanet"


@dataclass(frozen=True)
class Labeller:
    """A network, optionally with its probabilities deliberately distorted (see distort)."""

    spec: str
    distortion: str = ""

    @property
    def name(self) -> str:
        base = network_name(self.spec)
        return f"{base}+{self.distortion}" if self.distortion else base


#: Who labels the tuning scans of each dataset: strong and weak networks, networks that saw the
#: rooms (over-confident) and ones that did not, and distorted labels, so the rule meets every
#: kind of network on every kind of segment. DGCNN model_1 is honest on ScanNet only. (Distorted
#: model_6 labels of the S3DIS rooms were tried as well: they cost every real network in
#: cross-validation, model_6 itself -0.4 points, and were left out.)
LABELLERS: dict[str, list[Labeller]] = {
    "S3DIS": [
        Labeller(M6),
        Labeller(WEAK),
        Labeller(GPU),
        Labeller(BUNDLED),
    ],
    "ScanNet": [
        Labeller(M6),
        Labeller(M1),
        Labeller(WEAK),
        Labeller(GPU),
        Labeller(BUNDLED),
        Labeller(M1, "biased"),
    ],
    "synthetic": [Labeller(WEAK), Labeller(BUNDLED), Labeller(WEAK, "underconfident")],
    # the tuning rooms thinned to 3.3 cm (sparser segments, as another building's scanner)
    f"S3DIS {THIN * 100:.1f} cm": [Labeller(M6), Labeller(WEAK), Labeller(GPU), Labeller(BUNDLED)],
    # the tuning scans without their colour, labelled by what the pipeline then runs
    "S3DIS no colour": [Labeller(NOCOLOUR)],
    "ScanNet no colour": [Labeller(NOCOLOUR)],
}
#: Class confusions a biased network makes (from -> to; half of the first class's probability
#: moves to the second): furniture swapped, objects taken for the wall behind them.
BIAS = [(7, 8), (8, 7), (11, 2), (5, 2), (10, 12), (6, 2)]


def distort(probs: np.ndarray, kind: str) -> np.ndarray:
    """Probabilities of a deliberately different network: 'biased' (the confusions of BIAS),
    'overconfident' (temperature 0.5) or 'underconfident' (temperature 2)."""
    p = probs.astype(np.float64)
    if kind == "biased":
        for a, b in BIAS:
            moved = 0.6 * p[:, a]
            p[:, a] -= moved
            p[:, b] += moved
    elif kind in ("overconfident", "underconfident"):
        p = np.power(np.maximum(p, 1e-8), 2.0 if kind == "overconfident" else 0.5)
    else:
        raise ValueError(f"unknown distortion {kind!r}")
    return (p / p.sum(axis=1, keepdims=True)).astype(np.float32)


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


@dataclass
class Room:
    """One scan as one labeller labelled it: its offers, what is true of them, and what scoring
    a rule on it needs."""

    name: str
    dataset: str
    room: str  # scans of one room stay in one fold
    labeller: str
    gt: np.ndarray
    labels: np.ndarray
    offers: Offers
    truth: np.ndarray  # ground truth at each offer's point
    weight: np.ndarray  # per offer: inverse frequency of the true class, rooms weigh alike


def load_room(
    item: Item, who: Labeller, predictors: dict, min_support: float, structure: bool = True
) -> Room:
    """Offers of one scan (segments of the default geometry), with their truth and weights."""
    labels, probs = network_output(who.spec, item, predictors)
    if who.distortion:
        probs = distort(probs, who.distortion)
        labels = probs.argmax(axis=1)
    g = geometry_output("default", item)
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
        structure=structure_hint(g) if structure else None,
        has_colour=item.scan.rgb is not None,
    )
    truth = gt[offers.point]
    freq = np.bincount(gt[gt >= 0], minlength=13) / max(int((gt >= 0).sum()), 1)
    w = 1.0 / (freq[np.maximum(truth, 0)] + 0.02)
    useful = (truth == offers.label) | (truth == labels[offers.point])
    w = np.where(useful, w, 0.0)
    return Room(
        item.name,
        item.dataset,
        f"{item.dataset}/{item.room or item.name}",
        who.name,
        gt,
        labels,
        offers,
        truth,
        w / max(w.sum(), 1e-12),
    )


def fused_labels(room: Room, p: np.ndarray, threshold: float) -> np.ndarray:
    """The room's labels after taking each point's most probable offer above ``threshold``."""
    return best_offers(room.labels, room.offers.point, room.offers.label, p, threshold)


def features(room: Room, args: argparse.Namespace) -> np.ndarray:
    """The room's offer features, with the --drop-feature columns held constant (unusable)."""
    x = room.offers.features
    if not args.drop_feature:
        return x
    x = x.copy()
    x[:, [FEATURES.index(name) for name in args.drop_feature]] = 0.0
    return x


def fit(rooms: list[Room], args: argparse.Namespace) -> HistGradientBoostingClassifier:
    """The rule fitted on ``rooms``; every dataset weighs the same (times its --dataset-weight),
    and inside one every labelled scan."""
    per_dataset: dict[str, int] = {}
    for r in rooms:
        per_dataset[r.dataset] = per_dataset.get(r.dataset, 0) + 1
    x = np.concatenate([features(r, args) for r in rooms])
    y = np.concatenate([r.truth == r.offers.label for r in rooms])
    share = dict(args.dataset_weight or [])
    w = np.concatenate(
        [r.weight * share.get(r.dataset, 1.0) / per_dataset[r.dataset] for r in rooms]
    ) * len(rooms)
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


def gains(
    clf: HistGradientBoostingClassifier, rooms: list[Room], args: argparse.Namespace
) -> np.ndarray:
    """mIoU gain (points) of the rule on each room (rows) at each threshold (columns)."""
    thresholds = args.thresholds
    out = np.zeros((len(rooms), len(thresholds)))
    for i, r in enumerate(rooms):
        p = clf.predict_proba(features(r, args))[:, 1] if len(r.truth) else np.zeros(0)
        net = evaluate(r.gt, r.labels).miou or 0.0
        for j, t in enumerate(thresholds):
            out[i, j] = 100 * ((evaluate(r.gt, fused_labels(r, p, t)).miou or 0.0) - net)
    return out


def cross_validate(rooms: list[Room], args: argparse.Namespace) -> None:
    """Held-out gains per dataset x labeller at every threshold: rooms left out in ``args.cv``
    folds (every scan and labelling of a room in one fold), or with ``--cv-datasets`` a whole
    dataset left out at a time. The judging scans of bench/fusion_real.py are never read."""
    if args.cv_datasets:
        fold_of = {r.room: r.dataset for r in rooms}
    else:
        names = stable_order(sorted({r.room for r in rooms}))
        fold_of = {name: str(i % args.cv) for i, name in enumerate(names)}
    found: dict[tuple[str, str], list[np.ndarray]] = {}
    for k in sorted(set(fold_of.values())):
        test = [r for r in rooms if fold_of[r.room] == k]
        clf = fit([r for r in rooms if fold_of[r.room] != k], args)
        for r, g in zip(test, gains(clf, test, args), strict=True):
            kind = f"{r.dataset} slices" if r.name.endswith(" slice") else r.dataset
            found.setdefault((kind, r.labeller), []).append(g)
    how = "leave one dataset out" if args.cv_datasets else f"{args.cv} folds by room"
    print(
        f"\n### {how}: depth {args.depth} trees {args.trees} leaf {args.min_leaf} l2 {args.l2} "
        f"lr {args.learning_rate} (mean / worst gain, points)\n"
    )
    print("| dataset | labeller | scans | " + " | ".join(f"t={t}" for t in args.thresholds) + " |")
    print("|---" * (3 + len(args.thresholds)) + "|")
    for (dataset, labeller), values in sorted(found.items()):
        a = np.array(values)
        cells = " | ".join(
            f"{a[:, j].mean():+.2f} / {a[:, j].min():+.2f}" for j in range(a.shape[1])
        )
        print(f"| {dataset} | {labeller} | {len(a)} | {cells} |")
    every = np.concatenate([np.array(v) for v in found.values()])
    group_means = np.array([np.array(v).mean(axis=0) for v in found.values()])
    print(
        "| **all** | worst group mean / worst scan | "
        + str(len(every))
        + " | "
        + " | ".join(
            f"{group_means[:, j].min():+.2f} / {every[:, j].min():+.2f}"
            for j in range(every.shape[1])
        )
        + " |"
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


#: Height of the band above the floor a slice keeps (m): the S3DIS fragment is such a slice.
SLICE_HEIGHT = 1.0


def floor_slice(item: Item) -> Item:
    """The bottom SLICE_HEIGHT metres of a tuning scan, as a scan of its own in the same room
    (partial scans: the network and the geometry see only the slice)."""
    z = item.scan.xyz[:, 2]
    keep = z < np.percentile(z, 2) + SLICE_HEIGHT
    scan = Scan(
        xyz=item.scan.xyz[keep],
        rgb=None if item.scan.rgb is None else item.scan.rgb[keep],
        labels=None if item.scan.labels is None else item.scan.labels[keep],
    )
    name = f"{item.name} slice"
    return Item(
        name,
        scan,
        content_key(item.key, "slice", SLICE_HEIGHT),
        item.split,
        item.dataset,
        item.room,
    )


def load_rooms(args: argparse.Namespace) -> tuple[list[Room], list[Item]]:
    """Every tuning scan of every dataset, labelled by each of its dataset's labellers."""
    real = [
        i
        for i in load_items([str(AREA6), str(SCANNET)], args.judge, (0, 0, 0))
        if i.split == "tune"
    ]
    if args.slices:
        real += [floor_slice(i) for i in real]
    if args.variants:
        real += [thinned(i) for i in real if i.dataset == "S3DIS"]
        real += [
            colourless(i, f"{i.dataset} no colour")
            for i in real
            if i.dataset in ("S3DIS", "ScanNet")
        ]
    synth = calibration_rooms(args.synth_rooms, args.synth_floors, args.synth_points)
    predictors: dict = {}
    support = FusionParams().min_support
    rooms = []
    for item in real + synth:
        for who in LABELLERS[item.dataset]:
            if f"{item.dataset}:{who.name}" in (args.skip_labeller or []):
                continue
            t = time.perf_counter()
            rooms.append(load_room(item, who, predictors, support, args.structure))
            log.info("%s by %s: %.1f s", item.name, who.name, time.perf_counter() - t)
    return rooms, real + synth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--judge", type=int, default=10, help="real judging rooms left out")
    parser.add_argument("--synth-rooms", type=int, default=6)
    parser.add_argument("--synth-floors", type=int, default=1)
    parser.add_argument("--synth-points", type=int, default=100_000)
    parser.add_argument("--trees", type=int, default=50)
    parser.add_argument("--depth", type=int, default=2)
    parser.add_argument("--min-leaf", type=int, default=200, help="least samples per leaf")
    parser.add_argument("--l2", type=float, default=1.0, help="L2 regularisation of leaves")
    parser.add_argument("--learning-rate", type=float, default=0.1)
    parser.add_argument(
        "--thresholds",
        type=float,
        nargs="+",
        default=[FusionParams().flip_threshold],
        help="flip thresholds the cross-validation scores",
    )
    parser.add_argument(
        "--monotonic",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="constrain the rule to be monotone in the support of the offer and own label",
    )
    parser.add_argument("--cv", type=int, default=0, help="only cross-validate, in this many folds")
    parser.add_argument(
        "--cv-datasets", action="store_true", help="only cross-validate, one dataset left out"
    )
    parser.add_argument(
        "--drop-feature", action="append", choices=FEATURES, help="fit without this feature"
    )
    parser.add_argument(
        "--dataset-weight",
        action="append",
        type=lambda t: (t.partition("=")[0], float(t.partition("=")[2])),
        help="DATASET=W: that dataset weighs W times the others (repeat)",
    )
    parser.add_argument(
        "--skip-labeller", action="append", help="DATASET:LABELLER left out, e.g. S3DIS:randlanet"
    )
    parser.add_argument(
        "--slices",
        action="store_true",
        help=f"also fit on the bottom {SLICE_HEIGHT} m of every real tuning scan",
    )
    parser.add_argument(
        "--structure",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="offer the geometry's structure reading (--no-structure: the vote before issue 43)",
    )
    parser.add_argument(
        "--variants",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also fit on the real tuning scans thinned to 3.3 cm (S3DIS) and without colour",
    )
    parser.add_argument("--out", type=Path, default=MODEL_PATH)
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger("jointseg").setLevel(logging.WARNING)
    rooms, items = load_rooms(args)
    if args.cv or args.cv_datasets:
        cross_validate(rooms, args)
        return
    t = time.perf_counter()
    clf = fit(rooms, args)
    labellers = {d: [w.name for w in ws] for d, ws in LABELLERS.items()}
    body = {
        "features": list(FEATURES),
        "cell_size": DEFAULT_CELL_SIZE,
        **export(clf),
        "card": {
            "what": "P(a label offered by a point's segment or cell is right where the network "
            "disagrees)",
            "trained_on": {
                "scans": {
                    d: sorted({i.name for i in items if i.dataset == d})
                    for d in sorted({i.dataset for i in items})
                },
                "labellers": labellers,
                "distortions": "biased: 60 % of a class's probability moved to a confused "
                f"class for {BIAS}; over/underconfident: temperature 0.5 / 2",
                "synthetic_points": args.synth_points,
                "geometry": "GeometryParams() defaults",
                "weighting": "every dataset alike, times its dataset weight "
                f"{dict(args.dataset_weight or [])}; inside one every labelled scan alike; "
                "inside a scan offers by inverse true-class frequency",
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
            "data_terms": "real scans are derived from S3DIS (research use, cite Armeni et al. "
            "2016) and ScanNet (non-commercial research terms, cite Dai et al. 2017); the model "
            "stores only split thresholds and leaf values",
        },
    }
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(body, separators=(",", ":")))
    tmp.replace(args.out)
    print(
        f"{body['card']['samples']} samples from {len(items)} scans x labellers "
        f"({len(rooms)}), fitted in {time.perf_counter() - t:.1f} s -> {args.out} "
        f"({args.out.stat().st_size} bytes)"
    )


if __name__ == "__main__":
    main()
