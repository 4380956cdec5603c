"""Which way is up, on scans delivered as users deliver them: the frame stage's weighing judged
per source, on the tuning cases of a fit plan and on the judging rooms it leaves out.

    .venv/bin/python bench/up_axis.py                       # the shipped up_model.json
    .venv/bin/python bench/up_axis.py --model /tmp/up.json  # a model `jointseg fit up-axis` wrote
    .venv/bin/python bench/up_axis.py --fit                 # weights fitted here, in memory
    .venv/bin/python bench/up_axis.py --part miou           # z-up scans: kept +z? fused mIoU

Cases (made by jointseg.fitting.up_axis_cases, as `jointseg fit up-axis` makes them): every S3DIS
and ScanNet room delivered z up as it is, as LAS, y up (a plain export, a GLB, a phone app's
PLY), upside down, x up, tilted 5-20 degrees, cut to a 1.2 m slice or half a room, and cut into
camera frames; and the real captures of ../shared/data. The rooms and captures the plan
(default fit/up_axis.json) names are tuning cases, the other rooms judging ones. Gathered
evidence and the network's verdicts are cached under bench/_cache/up.

Prints per source and split: decisions right / wrong, wrong without a warning (confidence at or
above jointseg.frame.decide.UP_UNSURE), and the calibration of the confidence. Writes no model.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
from helpers.inputs import AREA6, BENCH, CACHE, DATA, SCANNET
from helpers.report import header
from helpers.scans import DATASET_NAMES

from jointseg.fitting.outputs import network_spec
from jointseg.fitting.scans import scan_files
from jointseg.fitting.up_axis import UpPlan, fit_weights, gather_all, read_plan
from jointseg.fitting.up_axis_cases import Case, Gathered, room_cases
from jointseg.frame import gravity, weigh
from jointseg.frame.decide import UP_UNSURE as UNSURE
from jointseg.frame.model import MODEL_FILE, read_up_model, weight_vector
from jointseg.frame.sources import SIGNED_AXES
from jointseg.io import read_scan
from jointseg.scan import Scan

#: The shipped model's plan.
PLAN = BENCH.parent / "fit" / "up_axis.json"
#: A real capture whose up nobody knows (its colours are segment colours): shown, not scored.
UNKNOWN_UP = DATA / "other_sensors" / "pcldata_region_growing_tutorial.pcd"


def all_cases(plan: UpPlan, base: Path) -> list[Case]:
    """The plan's tuning cases, and the same deliveries of every other room as judging ones."""
    from jointseg.fitting.up_axis import plan_cases

    tuning, _ = plan_cases(plan, base)
    tuned = {c.name for c in tuning}
    judging = []
    for path in scan_files([AREA6, SCANNET]):
        if path.stem in tuned:
            continue
        room = read_scan(path)
        room = Scan(room.xyz, room.rgb, room.labels, source_format="ply")
        kinds = tuple(plan.deliveries)
        for case in room_cases(path.stem, path.parent.name, room, seed=plan.seed, kinds=kinds,
                               n_views=plan.views):  # fmt: skip
            case.judging = True
            judging.append(case)
    unknown = Case(UNKNOWN_UP.stem, "other sensors", "as delivered", None, read_scan(UNKNOWN_UP))
    out = [*tuning, *judging, unknown]
    for case in out:
        case.source = DATASET_NAMES.get(case.source, case.source)
    return out


def decided(row: Gathered, p: np.ndarray) -> tuple[str, float]:
    """The axis chosen from the probabilities (the file's own axis kept on too little), and its
    confidence."""
    name = weigh.choose(p, row.evidence.file_axis)
    return name, float(p[SIGNED_AXES.index(name)])


def decide(row: Gathered, base_w: np.ndarray, full_w: np.ndarray, use_net: bool) -> np.ndarray:
    """The six probabilities, as jointseg.frame.decide weighs them, with these weights: the
    network's verdicts (all six cached) on the candidates it would judge, when it is asked."""
    evidence = row.evidence
    if not use_net or not row.net or not weigh.needs_judge(evidence, base_w):
        return weigh.weigh(evidence, base_weights=base_w).p
    judged = {a: row.net[a] for a in weigh.candidates(evidence, base_weights=base_w)}
    return weigh.weigh(evidence, judged, base_weights=base_w, full_weights=full_w).p


def table(rows: list[Gathered], base_w: np.ndarray, full_w: np.ndarray, use_net: bool) -> None:
    print(
        "| source | split | scans | right | wrong | wrong, no warning | warned "
        f"| right when sure (≥ {UNSURE:.2f}) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    sources = sorted({r.case.source for r in rows}, key=lambda s: (s == "other sensors", s))
    for source in sources:
        for split, flag in (("tuning", False), ("judging", True)):
            part = [r for r in rows if r.case.source == source and r.case.judging == flag]
            part = [r for r in part if r.case.truth is not None]
            if not part:
                continue
            got = [decided(r, decide(r, base_w, full_w, use_net)) for r in part]
            ok = [name == r.case.truth for r, (name, _) in zip(part, got, strict=True)]
            sure = [conf >= UNSURE for _, conf in got]
            right, n_sure = sum(ok), sum(sure)
            sure_right = sum(o and s for o, s in zip(ok, sure, strict=True))
            silent = n_sure - sure_right
            share = f"{sure_right / n_sure:.3f} ({sure_right}/{n_sure})" if n_sure else "-"
            print(
                f"| {source} | {split} | {len(part)} | {right} | {len(part) - right} | {silent} "
                f"| {len(part) - n_sure} | {share} |"
            )


def by_delivery(rows: list[Gathered], base_w: np.ndarray, full_w: np.ndarray) -> None:
    print("\n| delivery (judging rooms) | scans | right | wrong, no warning |")
    print("|---|---|---|---|")
    for d in sorted({r.case.delivery for r in rows if r.case.judging}):
        part = [r for r in rows if r.case.judging and r.case.delivery == d]
        got = [decided(r, decide(r, base_w, full_w, True)) for r in part]
        pairs = list(zip(part, got, strict=True))
        right = sum(name == r.case.truth for r, (name, _) in pairs)
        silent = sum(name != r.case.truth and conf >= UNSURE for r, (name, conf) in pairs)
        print(f"| {d} | {len(part)} | {right} | {silent} |")


def calibration(rows: list[Gathered], base_w: np.ndarray, full_w: np.ndarray) -> None:
    print("\n| confidence (judging scans) | decisions | right |")
    print("|---|---|---|")
    edges = [0.0, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99, 1.01]
    part = [r for r in rows if r.case.judging and r.case.truth is not None]
    got = [decided(r, decide(r, base_w, full_w, True)) for r in part]
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = [(r, n) for r, (n, c) in zip(part, got, strict=True) if lo <= c < hi]
        if sel:
            ok = sum(n == r.case.truth for r, n in sel)
            print(f"| {lo:.2f}-{min(hi, 1):.2f} | {len(sel)} | {ok / len(sel):.3f} |")


def arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--plan", type=Path, default=PLAN, help="the fit plan: its cases are tuning")
    ap.add_argument("--model", type=Path, default=MODEL_FILE, help="the up-axis model judged")
    ap.add_argument("--fit", action="store_true", help="judge weights fitted here on the tuning")
    ap.add_argument("--cache", type=Path, default=CACHE, help="gathered cases are kept here")
    ap.add_argument(
        "--part", choices=("decisions", "miou"), default="decisions",
        help="decisions: the tables above; miou: z-up scans' fused mIoU, auto against --up +z",
    )  # fmt: skip
    return ap.parse_args()


def main() -> None:
    args = arguments()
    header("up axis per source and delivery")
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.part == "miou":
        miou_part(read_plan(args.plan), args.plan.parent)
        return
    plan = read_plan(args.plan)
    body = read_up_model(args.model)
    axis = weight_vector(body, "axis_weights", gravity.AXIS_SIZE, args.model)
    sign = weight_vector(body, "sign_weights", gravity.SIGN_SIZE, args.model)
    spec = network_spec(plan.judge, args.plan.parent)
    rows = gather_all(all_cases(plan, args.plan.parent), spec, (axis, sign), args.cache)
    if args.fit:
        tuning = [r for r in rows if not r.case.judging]
        base_w, full_w = fit_weights(tuning, plan.l2, plan.delivery_weight)
        print(f"fitted here: base {np.round(base_w, 4).tolist()}, full {np.round(full_w, 4)}")
    else:
        base_w, full_w = weigh.fitted_weights(args.model)
    print(f"{len(rows)} cases; gathering took {sum(r.seconds for r in rows):.0f} s")
    print("\nbefore the network (file, capture, geometry):\n")
    table(rows, base_w, full_w, use_net=False)
    print("\nweighed with the network's verdict (the default):\n")
    table(rows, base_w, full_w, use_net=True)
    by_delivery(rows, base_w, full_w)
    calibration(rows, base_w, full_w)
    print("\nother sensors, as decided:")
    for r in rows:
        if r.case.source == "other sensors":
            name, conf = decided(r, decide(r, base_w, full_w, True))
            print(f"  {r.case.name}: {name} ({conf:.2f}); truth {r.case.truth or 'unknown'}")


def miou_part(plan: UpPlan, base: Path) -> None:
    """Every labelled scan delivered z up (all of ../shared/data): the decision, and the fused
    mIoU of the judging scans with the default frame stage against the same code with
    ``--up +z``."""
    from jointseg.pipeline import PipelineConfig, load_predictor, run

    tuned = {p.stem for p in scan_files([base / r for r in plan.rooms])}
    config = PipelineConfig()
    forced = config.model_copy(update={"frame": config.frame.model_copy(update={"up": "+z"})})
    predictor = load_predictor(config.network)
    print("| scan | split | decided | levelled | fused mIoU auto | fused mIoU --up +z | diff |")
    print("|---|---|---|---|---|---|---|")
    kept = total = 0
    diffs = []
    for path in [*scan_files([AREA6]), DATA / "s3dis_fragment.ply", *scan_files([SCANNET])]:
        scan = read_scan(path)
        judging = path.stem not in tuned and path.parent.name != "data"
        auto = run(scan, config, predictor=predictor)
        assert auto.frame is not None
        total += 1
        kept += auto.frame.up.axis == "+z"
        cells = ["-", "-", "-"]
        if judging and auto.metrics is not None:
            fixed = run(scan, forced, predictor=predictor)
            a, b = auto.metrics["fused"].miou or 0.0, (fixed.metrics or {})["fused"].miou or 0.0
            diffs.append(100 * (a - b))
            cells = [f"{100 * a:.2f}", f"{100 * b:.2f}", f"{100 * (a - b):+.2f}"]
        split = "judging" if judging else "tuning"
        decision = f"{auto.frame.up.axis} ({auto.frame.up.confidence:.2f}) | {auto.frame.levelled}"
        print(f"| {path.stem} | {split} | {decision} | {' | '.join(cells)} |")
    worst = max((abs(d) for d in diffs), default=0.0)
    print(
        f"\nkept +z: {kept} / {total}; judging scans' fused mIoU auto - forced: "
        f"max |diff| {worst:.2f} points over {len(diffs)} scans"
    )


if __name__ == "__main__":
    main()
