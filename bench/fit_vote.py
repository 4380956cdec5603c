"""Cross-validate the learned vote's fit: held-out mIoU gains per dataset x labeller.

The scans, labellers, weights and tree settings are a fit plan's (default fit/vote.json, the
shipped model's); the rooms come from the package (`jointseg.fitting.vote`), with the networks'
and geometry's outputs cached under bench/_cache. Rooms are left out in --cv N folds (every scan
and labelling of a room in one), or with --cv-datasets a whole dataset at a time; every fold's
rule is fitted as `jointseg fit vote` fits, and the held-out rooms' gains are printed at each
--thresholds value. This script writes no model: `jointseg fit vote --plan PLAN --out FILE`
does.

    .venv/bin/python bench/fit_vote.py --cv 5 --thresholds 0.5 0.6 0.7
    .venv/bin/python bench/fit_vote.py --cv-datasets --depth 3 --trees 100
    .venv/bin/python bench/fit_vote.py --cv 5 --dataset-weight ScanNet=2 --skip-dataset synthetic
    .venv/bin/python bench/fit_vote.py --cv 5 --fit-geometry-version 8
    .venv/bin/python bench/fit_vote.py --cv 5 --thresholds 0.5 --metric-iou 0.8

With --fit-geometry-version N every fold is fitted on the offers of the geometry an older
commit cached (its jointseg.fitting.outputs.STRUCTURE_VERSION was N; run that commit's
`jointseg fit vote --cache bench/_cache` first) and judged on the held-out rooms' offers of
today's geometry: what shipping a geometry change without refitting the vote does.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

import numpy as np
from helpers.inputs import BENCH, CACHE
from helpers.report import LOSS_BAR, header, metric_iou_value

from jointseg.fitting import outputs
from jointseg.fitting.vote import Room, Sources, VotePlan, load_rooms, read_plan
from jointseg.fitting.vote_trees import features, fit_trees
from jointseg.fusion.learned import best_offers, seen_fixtures
from jointseg.fusion.offers import FEATURES
from jointseg.fusion.params import FusionParams
from jointseg.fusion.thresholds import offer_thresholds
from jointseg.metrics import evaluate
from jointseg.training.data import stable_order

#: The shipped vote's plan.
PLAN = BENCH.parent / "fit" / "vote.json"


def gains(
    clf: Any,
    rooms: list[Room],
    plan: VotePlan,
    thresholds: list[float],
    metric_iou: float | str = 1.0,
    seen_fixture_share: float = 1.0,
) -> np.ndarray:
    """mIoU gain (points) of the rule on each room (rows) at each threshold (columns), each
    offer's threshold weighed by the classes' sizes as ``fusion.metric_iou`` weighs it, and the
    offers ``fusion.seen_fixture_share`` refuses left out."""
    out = np.zeros((len(rooms), len(thresholds)))
    for i, r in enumerate(rooms):
        x = features(r, plan.fit.drop_features)
        p = clf.predict_proba(x)[:, 1] if len(r.truth) else np.zeros(0)
        p = np.where(seen_fixtures(r.offers.features, r.offers.label, seen_fixture_share), 0.0, p)
        net = evaluate(r.gt, r.labels).miou or 0.0
        own = r.labels[r.offers.point]
        for j, t in enumerate(thresholds):
            at = offer_thresholds(r.classes, own, r.offers.label, t, metric_iou)
            fused = best_offers(r.labels, r.offers.point, r.offers.label, p, at)
            out[i, j] = 100 * ((evaluate(r.gt, fused).miou or 0.0) - net)
    return out


def folds(rooms: list[Room], n: int, by_dataset: bool) -> dict[str, str]:
    """Each room's fold: its dataset, or one of ``n`` folds in name-hash order."""
    if by_dataset:
        return {r.room: r.dataset for r in rooms}
    names = stable_order(sorted({r.room for r in rooms}))
    return {name: str(i % n) for i, name in enumerate(names)}


def cross_validate(
    rooms: list[Room],
    plan: VotePlan,
    fold_of: dict[str, str],
    thresholds: list[float],
    fit_rooms: list[Room] | None = None,
    metric_iou: float | str = 1.0,
    seen_fixture_share: float = 1.0,
) -> dict[tuple[str, str], list[tuple[str, np.ndarray]]]:
    """Held-out gains per (dataset, labeller) and scan, every fold fitted without its rooms
    (on ``fit_rooms``, the same scans and labellers in the same order, where given)."""
    weights = {d.name: d.weight for d in plan.datasets}
    fit_rooms = rooms if fit_rooms is None else fit_rooms
    found: dict[tuple[str, str], list[tuple[str, np.ndarray]]] = {}
    for k in sorted(set(fold_of.values())):
        test = [r for r in rooms if fold_of[r.room] == k]
        clf = fit_trees([r for r in fit_rooms if fold_of[r.room] != k], plan.fit, weights)
        held_out = gains(clf, test, plan, thresholds, metric_iou, seen_fixture_share)
        for r, g in zip(test, held_out, strict=True):
            kind = f"{r.dataset} slices" if r.name.endswith(" slice") else r.dataset
            found.setdefault((kind, r.labeller), []).append((r.name, g))
    return found


def rooms_at_version(plan: VotePlan, base: Path, version: int) -> list[Room]:
    """The plan's rooms with the geometry an older commit cached (STRUCTURE_VERSION
    ``version``); a scan whose geometry of that version is not in the cache stops the run,
    since today's code would compute it under the old key."""
    current, original = outputs.STRUCTURE_VERSION, outputs.cached

    def only_cached(path: Path | None, compute: Any) -> dict[str, np.ndarray]:
        if path is not None and path.parent.name == "geo" and not path.is_file():
            raise SystemExit(f"{path}: no geometry of version {version} cached; run that "
                             f"version's `jointseg fit vote --cache {CACHE}` first")  # fmt: skip
        return original(path, compute)

    outputs.STRUCTURE_VERSION, outputs.cached = version, only_cached
    try:
        return load_rooms(plan, base, Sources({}, CACHE)).rooms
    finally:
        outputs.STRUCTURE_VERSION, outputs.cached = current, original


def table(
    found: dict[tuple[str, str], list[tuple[str, np.ndarray]]], thresholds: list[float]
) -> None:
    """Mean / worst gain per dataset x labeller, the worst group and scan over all, how many
    scans lose more than LOSS_BAR, and which."""
    print("| dataset | labeller | scans | " + " | ".join(f"t={t}" for t in thresholds) + " |")
    print("|---" * (3 + len(thresholds)) + "|")
    for (dataset, labeller), named in sorted(found.items()):
        a = np.array([g for _, g in named])
        cells = " | ".join(
            f"{a[:, j].mean():+.2f} / {a[:, j].min():+.2f}" for j in range(a.shape[1])
        )
        print(f"| {dataset} | {labeller} | {len(a)} | {cells} |")
    every = np.concatenate([np.array([g for _, g in v]) for v in found.values()])
    group_means = np.array([np.array([g for _, g in v]).mean(axis=0) for v in found.values()])
    cells = " | ".join(
        f"{group_means[:, j].min():+.2f} / {every[:, j].min():+.2f}" for j in range(len(thresholds))
    )
    print(f"| **all** | worst group mean / worst scan | {len(every)} | {cells} |")
    losing = " | ".join(str(int((every[:, j] < -LOSS_BAR).sum())) for j in range(len(thresholds)))
    print(f"| **all** | scans losing over {LOSS_BAR} points | {len(every)} | {losing} |")
    print(f"\nScans losing over {LOSS_BAR} points at any threshold:\n")
    for (dataset, labeller), named in sorted(found.items()):
        for name, g in named:
            if (g < -LOSS_BAR).any():
                print(f"- {name} ({dataset}, {labeller}): " + ", ".join(f"{v:+.2f}" for v in g))


def adjusted(plan: VotePlan, args: argparse.Namespace) -> VotePlan:
    """The plan with this run's dataset weights, datasets left out and dropped features."""
    weights = dict(args.dataset_weight or [])
    datasets = [
        d.model_copy(update={"weight": weights.get(d.name, d.weight)})
        for d in plan.datasets
        if d.name not in (args.skip_dataset or [])
    ]
    fit = plan.fit.model_copy(update={"drop_features": args.drop_feature or []})
    return plan.model_copy(update={"datasets": datasets, "fit": fit})


def arguments() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--plan", type=Path, default=PLAN, help="the fit plan (JSON)")
    parser.add_argument("--cv", type=int, default=5, help="folds by room")
    parser.add_argument("--cv-datasets", action="store_true", help="leave one dataset out")
    parser.add_argument(
        "--thresholds", type=float, nargs="+", default=[FusionParams().flip_threshold]
    )
    for name in ("trees", "depth", "min-leaf"):
        parser.add_argument(f"--{name}", type=int, help="(default: the plan's)")
    for name in ("l2", "learning-rate"):
        parser.add_argument(f"--{name}", type=float, help="(default: the plan's)")
    parser.add_argument(
        "--metric-iou",
        type=metric_iou_value,
        default=FusionParams().metric_iou,
        help="fusion.metric_iou: auto, or one IoU for every class (1: one threshold)",
    )
    parser.add_argument(
        "--seen-fixture-share",
        type=float,
        default=FusionParams().seen_fixture_share,
        help="fusion.seen_fixture_share (1: the rule off)",
    )
    parser.add_argument("--monotonic", action=argparse.BooleanOptionalAction, default=None)
    parser.add_argument("--structure", action=argparse.BooleanOptionalAction, default=None)
    parser.add_argument("--drop-feature", action="append", choices=FEATURES)
    parser.add_argument(
        "--dataset-weight",
        action="append",
        type=lambda t: (t.partition("=")[0], float(t.partition("=")[2])),
        help="DATASET=W: that dataset weighs W (repeat)",
    )
    parser.add_argument("--skip-dataset", action="append", help="a dataset of the plan left out")
    parser.add_argument(
        "--fit-geometry-version", type=int, help="fit on an older commit's cached geometry"
    )
    return parser.parse_args()


def main() -> None:
    args = arguments()
    header("learned vote, cross-validated")
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    logging.getLogger("jointseg").setLevel(logging.WARNING)
    logging.getLogger("jointseg.fitting.vote").setLevel(logging.INFO)
    overrides = {
        "trees": args.trees,
        "depth": args.depth,
        "min_leaf": args.min_leaf,
        "l2": args.l2,
        "learning_rate": args.learning_rate,
        "monotonic": args.monotonic,
        "structure": args.structure,
    }
    plan = adjusted(read_plan(args.plan, **overrides), args)
    rooms = load_rooms(plan, args.plan.parent, Sources({}, CACHE)).rooms
    fit_rooms = None
    if args.fit_geometry_version is not None:
        fit_rooms = rooms_at_version(plan, args.plan.parent, args.fit_geometry_version)
        same = [(r.dataset, r.name, r.labeller) for r in rooms]
        if [(r.dataset, r.name, r.labeller) for r in fit_rooms] != same:
            raise SystemExit("the older geometry's rooms are not the same scans and labellers")
    fold_of = folds(rooms, args.cv, args.cv_datasets)
    found = cross_validate(rooms, plan, fold_of, args.thresholds, fit_rooms, args.metric_iou,
                           args.seen_fixture_share)  # fmt: skip
    how = "leave one dataset out" if args.cv_datasets else f"{args.cv} folds by room"
    how += f", metric_iou {args.metric_iou}, seen_fixture_share {args.seen_fixture_share}"
    if fit_rooms is not None:
        how += f", fitted on geometry version {args.fit_geometry_version}"
    print(f"\n### {how}: {plan.fit.model_dump()} (mean / worst gain, points)\n")
    table(found, args.thresholds)


if __name__ == "__main__":
    main()
