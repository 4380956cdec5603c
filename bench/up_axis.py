"""Which way is up, on scans delivered as users deliver them: fit the frame stage's weighing
on tuning scans, judge it on the others, per source.

    python bench/up_axis.py --fit     # gather (cached), fit jointseg/frame/up_model.json, judge
    python bench/up_axis.py           # judge the weights in up_model.json
    python bench/up_axis.py --cache F # where the gathered features are kept (default /tmp)
    python bench/up_axis.py --part miou  # z-up scans: kept +z? fused mIoU auto vs --up +z

Sources (each room split into tuning or judging, and every delivery of a room on its side):

- S3DIS and ScanNet rooms delivered z up as they are, as LAS, y up (a plain export, a GLB, a
  phone app's PLY), upside down, x up, tilted 5-20 degrees, cut to a 1.2 m slice or half a room;
- camera frames: single views cut from those rooms along a depth camera's frustum, in the
  camera's frame (y down, z forward), as a plain PLY or as an organised PCD;
- other sensors: the real captures of ../shared/data (camera frames, truth from data/README.md).

Prints per source and split: decisions right / wrong, wrong without a warning (confidence at or
above jointseg.frame.decide.UNSURE), and the calibration of the confidence.
"""

from __future__ import annotations

import argparse
import logging
import pickle
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from jointseg.frame import gravity, weigh
from jointseg.frame.colour import decide_colour
from jointseg.frame.decide import UP_UNSURE as UNSURE
from jointseg.frame.decide import gather, judge_candidates, rotation_about
from jointseg.frame.params import FrameParams
from jointseg.frame.sources import SIGNED_AXES
from jointseg.io import read_scan
from jointseg.network.judge import crop_labeller
from jointseg.network.registry import load
from jointseg.scan import Scan
from jointseg.synth.views import camera_view

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
#: Rooms judged on (every delivery of them); the rest are tuned on. ScanNet scans of one room
#: stay on one side (scene0002_* etc.).
JUDGING_ROOMS = (
    "area6_office_4", "area6_office_7", "area6_office_13", "area6_office_16", "area6_office_20",
    "area6_office_24", "area6_office_27", "area6_office_31", "area6_office_35", "area6_hallway_4",
    "area6_pantry_1", "area6_office_3", "scene0002", "scene0005", "scene0007",
)  # fmt: skip


@dataclass
class Case:
    """One delivered scan and the truth about it."""

    name: str
    source: str
    delivery: str
    judging: bool
    truth: str | None  # signed file axis nearest the true up; None: unknown
    scan: Scan


def to_axis(target: str) -> np.ndarray:
    """A proper rotation taking +z to the signed axis ``target``."""
    want = gravity.AXES[target]
    if abs(want[2]) > 0.5:
        return np.eye(3) if want[2] > 0 else rotation_about(np.array([1.0, 0, 0]), 180)
    return rotation_about(np.cross([0.0, 0.0, 1.0], want), 90)


def nearest_axis(up: np.ndarray) -> str:
    i = int(np.argmax(np.abs(up)))
    return ("+" if up[i] > 0 else "-") + "xyz"[i]


def deliveries(room: Scan, rng: np.random.Generator) -> list[tuple[str, str, Scan]]:
    """(delivery, truth, scan) for one z-up room."""

    def turned(r: np.ndarray, **kw: object) -> Scan:
        return replace(room, xyz=room.xyz @ r.T, **kw)  # type: ignore[arg-type]

    tilt = rotation_about(np.array([*rng.normal(size=2), 0.0]), rng.uniform(5, 20))
    yaw = rotation_about(np.array([0.0, 0.0, 1.0]), rng.uniform(0, 360))
    h = room.xyz[:, 2]
    slice_ = h < np.quantile(h, 0.005) + 1.2
    half = room.xyz[:, 0] < np.median(room.xyz[:, 0])
    out = [
        ("z up, as is", "+z", room),
        ("z up, LAS", "+z", replace(room, source_format="las")),
        ("y up export", "+y", turned(to_axis("+y") @ yaw)),
        ("y up GLB", "+y", turned(to_axis("+y"), source_format="glb",
                                  meta={"up_convention": {"axis": "+y", "source": "glTF"}})),
        ("y up phone PLY", "+y", turned(to_axis("+y") @ yaw,
                                        meta={"comments": ["Exported by Polycam"]})),
        ("upside down", "-z", turned(to_axis("-z") @ yaw)),
        ("x up", "+x", turned(to_axis("+x") @ yaw)),
        ("z up, tilted", "+z", turned(tilt @ yaw)),
        ("z up, 1.2 m slice", "+z", replace(room, xyz=room.xyz[slice_], rgb=_part(room.rgb, slice_),
                                            labels=_part(room.labels, slice_))),
        ("z up, half room", "+z", replace(room, xyz=room.xyz[half], rgb=_part(room.rgb, half),
                                          labels=_part(room.labels, half))),
    ]  # fmt: skip
    return out


def _part(a: np.ndarray | None, m: np.ndarray) -> np.ndarray | None:
    return None if a is None else a[m]


def views(room: Scan, rng: np.random.Generator, n: int) -> list[tuple[str, str, Scan]]:
    out = []
    for i in range(n):
        v = camera_view(room, rng)
        if v is None:
            continue
        scan = v.scan
        if i % 2:  # delivered as an organised PCD
            scan = replace(scan, source_format="pcd", meta={"organised": [640, 480]})
        kind = "organised PCD" if i % 2 else "plain PLY"
        out.append((f"camera frame, {kind}", nearest_axis(v.up), scan))
    return out


def cases(n_views: int, seed: int) -> list[Case]:
    rng = np.random.default_rng(seed)
    out: list[Case] = []
    for folder, source in (("s3dis_area6", "S3DIS"), ("scannet", "ScanNet")):
        for path in sorted((SHARED / folder).glob("*.ply")):
            room = read_scan(path)
            room = Scan(room.xyz, room.rgb, room.labels, source_format="ply")
            judging = any(path.stem.startswith(j) for j in JUDGING_ROOMS)
            for delivery, truth, scan in deliveries(room, rng):
                out.append(Case(path.stem, source, delivery, judging, truth, scan))
            for delivery, truth, scan in views(room, rng, n_views):
                out.append(Case(path.stem, "camera frames", delivery, judging, truth, scan))
    others = {
        "pcldata_capture0001": "-y",
        "pcl_table_scene_mug_stereo_textured": "-y",
        "pcldata_region_growing_tutorial": None,
    }
    for stem, truth in others.items():
        scan = read_scan(SHARED / "other_sensors" / f"{stem}.pcd")
        out.append(Case(stem, "other sensors", "as delivered", False, truth, scan))
    scan = read_scan(SHARED / "real_indoor_unlabelled.pcd")
    out.append(Case("real_indoor_unlabelled", "other sensors", "as delivered", False, "-y", scan))
    return out


def gather_all(items: list[Case], judge_all: bool) -> list[dict]:
    """Per case: the base features of the six candidates and the network's of each."""
    label = crop_labeller(load()) if judge_all else None
    params = FrameParams()
    rows = []
    for n, c in enumerate(items):
        t = time.perf_counter()
        rng = np.random.default_rng(0)
        centre = np.median(c.scan.xyz[:: max(1, len(c.scan) // 100_000)], axis=0)
        sample = gravity.frame_sample(c.scan.xyz - centre, rng)
        g = gather(c.scan, sample, params)
        colour = decide_colour(c.scan.rgb, True)
        judged = {}
        if label is not None:
            judged = judge_candidates(g, c.scan, centre, colour, label, list(SIGNED_AXES))
        rows.append(
            {
                "name": c.name,
                "source": c.source,
                "delivery": c.delivery,
                "judging": c.judging,
                "truth": c.truth,
                "evidence": g.evidence,
                "net": judged,
                "seconds": time.perf_counter() - t,
            }
        )
        if n % 25 == 0:
            logging.info("gathered %d / %d cases", n + 1, len(items))
    return rows


def regather_network(rows: list[dict], items: list[Case], over: int) -> None:
    """The network's verdicts again for the cases of more than ``over`` points."""
    big = [i for i, c in enumerate(items) if len(c.scan) > over]
    logging.info("judging %d cases of more than %d points again", len(big), over)
    fresh = gather_all([items[i] for i in big], judge_all=True)
    for i, new in zip(big, fresh, strict=True):
        assert (rows[i]["name"], rows[i]["delivery"]) == (new["name"], new["delivery"])
        rows[i]["net"] = new["net"]


def decided(row: dict, p: np.ndarray) -> tuple[str, float]:
    """The axis chosen from the probabilities (the file's own axis kept on too little), and its
    confidence."""
    name = weigh.choose(p, row["evidence"].file_axis)
    return name, float(p[SIGNED_AXES.index(name)])


def decide(row: dict, base_w: np.ndarray, full_w: np.ndarray, use_net: bool) -> np.ndarray:
    """The six probabilities, as jointseg.frame.decide weighs them, with these weights: the
    network's verdicts (all six cached) on the candidates it would judge, when it is asked."""
    evidence = row["evidence"]
    if not use_net or not row["net"] or not weigh.needs_judge(evidence, base_w):
        return weigh.weigh(evidence, base_weights=base_w).p
    judged = {a: row["net"][a] for a in weigh.candidates(evidence, base_weights=base_w)}
    return weigh.weigh(evidence, judged, base_weights=base_w, full_weights=full_w).p


#: How often scans arrive each way, relative to the bench's even mix: the fit weighs each case by
#: it, so its priors are the world's, not the bench's (z up as is most; upside down and x up rare).
DELIVERY_WEIGHT = {
    "z up, as is": 6.0, "z up, LAS": 2.0, "z up, tilted": 2.0, "z up, 1.2 m slice": 2.0,
    "z up, half room": 2.0, "upside down": 0.2, "x up": 0.3,
}  # fmt: skip


def _nll(w: np.ndarray, rows: list[dict], full: bool, base_w: np.ndarray, l2: float) -> float:
    total = 0.0
    for r in rows:
        base = r["evidence"].base()
        if full:
            names = weigh.candidates(r["evidence"], base_weights=base_w)
            top = [SIGNED_AXES.index(a) for a in names]
            if r["truth"] not in names:
                continue
            x = np.array([np.concatenate([base[i], r["net"][SIGNED_AXES[i]]]) for i in top])
            t = names.index(r["truth"])
        else:
            x, t = base, SIGNED_AXES.index(r["truth"])
        z = x @ w
        total += DELIVERY_WEIGHT.get(r["delivery"], 1.0) * float(np.logaddexp.reduce(z) - z[t])
    return total + l2 * float(w @ w)


def fit(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    known = [r for r in rows if r["truth"] is not None]
    base = minimize(_nll, np.ones(len(weigh.BASE_FEATURES)), args=(known, False, None, 1.0)).x
    x0 = np.r_[base, np.zeros(len(weigh.FULL_FEATURES) - len(base))]
    full = minimize(_nll, x0, args=(known, True, base, 1.0), method="L-BFGS-B").x
    return base, full


def table(rows: list[dict], base_w: np.ndarray, full_w: np.ndarray, use_net: bool) -> None:
    print(
        "| source | split | scans | right | wrong | wrong, no warning | warned "
        f"| right when sure (≥ {UNSURE:.2f}) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    sources = sorted({r["source"] for r in rows}, key=lambda s: (s == "other sensors", s))
    for source in sources:
        for split, flag in (("tuning", False), ("judging", True)):
            part = [r for r in rows if r["source"] == source and r["judging"] == flag]
            part = [r for r in part if r["truth"] is not None]
            if not part:
                continue
            right = wrong = silent = warned = sure = sure_right = 0
            for r in part:
                name, conf = decided(r, decide(r, base_w, full_w, use_net))
                ok = name == r["truth"]
                right += ok
                wrong += not ok
                if conf >= UNSURE:
                    sure += 1
                    sure_right += ok
                    silent += not ok
                else:
                    warned += 1
            share = f"{sure_right / sure:.3f} ({sure_right}/{sure})" if sure else "-"
            print(
                f"| {source} | {split} | {len(part)} | {right} | {wrong} | {silent} | {warned} "
                f"| {share} |"
            )


def by_delivery(rows: list[dict], base_w: np.ndarray, full_w: np.ndarray) -> None:
    print("\n| delivery (judging rooms) | scans | right | wrong, no warning |")
    print("|---|---|---|---|")
    for d in sorted({r["delivery"] for r in rows if r["judging"]}):
        part = [r for r in rows if r["judging"] and r["delivery"] == d]
        got = [decided(r, decide(r, base_w, full_w, True)) for r in part]
        pairs = list(zip(part, got, strict=True))
        right = sum(name == r["truth"] for r, (name, _) in pairs)
        silent = sum(name != r["truth"] and conf >= UNSURE for r, (name, conf) in pairs)
        print(f"| {d} | {len(part)} | {right} | {silent} |")


def calibration(rows: list[dict], base_w: np.ndarray, full_w: np.ndarray) -> None:
    print("\n| confidence (judging scans) | decisions | right |")
    print("|---|---|---|")
    edges = [0.0, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.99, 1.01]
    part = [r for r in rows if r["judging"] and r["truth"] is not None]
    got = [decided(r, decide(r, base_w, full_w, True)) for r in part]
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = [(r, n) for r, (n, c) in zip(part, got, strict=True) if lo <= c < hi]
        if sel:
            ok = sum(n == r["truth"] for r, n in sel)
            print(f"| {lo:.2f}-{min(hi, 1):.2f} | {len(sel)} | {ok / len(sel):.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--fit", action="store_true", help="fit the weighing on the tuning scans")
    ap.add_argument("--views", type=int, default=4, help="camera views cut from each room")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/jointseg_up_axis_cases.pkl"))
    ap.add_argument(
        "--regather-evidence", action="store_true",
        help="gather the evidence before the network again, keeping the cached verdicts",
    )  # fmt: skip
    ap.add_argument(
        "--regather-network-over", type=int, default=0, metavar="N",
        help="judge again the cases of more than N points (after a change of the judge's sample)",
    )  # fmt: skip
    ap.add_argument(
        "--part", choices=("decisions", "miou"), default="decisions",
        help="decisions: the tables above; miou: z-up scans' fused mIoU, auto against --up +z",
    )  # fmt: skip
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.part == "miou":
        miou_part()
        return
    if args.cache.is_file():
        rows = pickle.loads(args.cache.read_bytes())
        if args.regather_evidence:  # the same cases (same seed); the network's verdicts kept
            fresh = gather_all(cases(args.views, args.seed), judge_all=False)
            for old, new in zip(rows, fresh, strict=True):
                assert (old["name"], old["delivery"]) == (new["name"], new["delivery"])
                old["evidence"] = new["evidence"]
            args.cache.write_bytes(pickle.dumps(rows))
        if args.regather_network_over:  # the verdicts of the scans the judge subsamples
            regather_network(rows, cases(args.views, args.seed), args.regather_network_over)
            args.cache.write_bytes(pickle.dumps(rows))
    else:
        rows = gather_all(cases(args.views, args.seed), judge_all=True)
        args.cache.write_bytes(pickle.dumps(rows))
    if args.fit:  # the file's weighing is not read: it may be for other features
        base_w, full_w = fit([r for r in rows if not r["judging"]])
        write_model(base_w, full_w, rows)
    else:
        base_w, full_w = weigh.fitted_weights()
    print(f"{len(rows)} cases; gathering took {sum(r['seconds'] for r in rows):.0f} s")
    print("\nbefore the network (file, capture, geometry):\n")
    table(rows, base_w, full_w, use_net=False)
    print("\nweighed with the network's verdict (the default):\n")
    table(rows, base_w, full_w, use_net=True)
    by_delivery(rows, base_w, full_w)
    calibration(rows, base_w, full_w)
    print("\nother sensors, as decided:")
    for r in rows:
        if r["source"] == "other sensors":
            name, conf = decided(r, decide(r, base_w, full_w, True))
            print(f"  {r['name']}: {name} ({conf:.2f}); truth {r['truth'] or 'unknown'}")


def miou_part() -> None:
    """Every labelled scan delivered z up (all of ../shared/data): the decision, and the fused
    mIoU of the judging scans with the default frame stage against the same code with
    ``--up +z``."""
    from jointseg.pipeline import PipelineConfig, load_predictor, run

    config = PipelineConfig()
    forced = config.model_copy(update={"frame": config.frame.model_copy(update={"up": "+z"})})
    predictor = load_predictor(config.network)
    print("| scan | split | decided | levelled | fused mIoU auto | fused mIoU --up +z | diff |")
    print("|---|---|---|---|---|---|---|")
    kept = total = 0
    diffs = []
    paths = [*sorted((SHARED / "s3dis_area6").glob("*.ply")), SHARED / "s3dis_fragment.ply"]
    paths += sorted((SHARED / "scannet").glob("*.ply"))
    for path in paths:
        scan = read_scan(path)
        judging = any(path.stem.startswith(j) for j in JUDGING_ROOMS)
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
        decided = f"{auto.frame.up.axis} ({auto.frame.up.confidence:.2f}) | {auto.frame.levelled}"
        print(f"| {path.stem} | {split} | {decided} | {' | '.join(cells)} |")
    print(
        f"\nkept +z: {kept} / {total}; judging scans' fused mIoU auto - forced: "
        f"max |diff| {max(abs(d) for d in diffs):.2f} points over {len(diffs)} scans"
    )


def write_model(base_w: np.ndarray, full_w: np.ndarray, rows: list[dict]) -> None:
    import json

    model = json.loads(weigh.MODEL_FILE.read_text())
    model["weigh"] = {
        "features": list(weigh.FULL_FEATURES),
        "base": np.round(base_w, 4).tolist(),
        "full": np.round(full_w, 4).tolist(),
        "fitted_on": sorted({r["name"] for r in rows if not r["judging"]}),
        "command": "python bench/up_axis.py --fit",
    }
    weigh.MODEL_FILE.write_text(json.dumps(model, indent=1) + "\n")
    print(f"wrote {weigh.MODEL_FILE}: base {model['weigh']['base']}, full {model['weigh']['full']}")


if __name__ == "__main__":
    main()
