"""Learning from corrections (issue 66): a simulated user corrects one scan, the network adapts,
and the next scans come out better.

The user corrects the ``--clicks`` largest wrongly labelled segments of one scan (each gets its
majority true class, as bench/noc.py's clicks: one edit ``{"segments": [id], "label": c}``
through jointseg.labels), saves that version, and runs ``jointseg adapt`` on it
(jointseg.adapt.learn.adapt, the same code). Every scan is run through the real pipeline
(defaults, the frame decided as for a user) with the bundled network and with the adapted
model; the score is fused mIoU over the classes present in the truth (bench/noc.py's).

- **ScanNet**, rooms scanned more than once: the room's first scan is corrected; judged on the
  room's other scans (re-scans) and on every scan of the other rooms. Rooms split as the other
  benches split them (judging: scene0002, scene0005, scene0007; tuning: the rest): the
  adaptation's settings were chosen on the tuning rooms.
- **S3DIS Area_6**: a tuning room is corrected; judged on the 10 judging rooms (other rooms:
  what an owner's model does to a building it has not seen).

    .venv/bin/python bench/adapt.py [--clicks 20] [--datasets scannet,s3dis] [--steps 300]
        [--keep-weight 1.0] [--s3dis-rooms 3]
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from helpers.inputs import AREA6, SCANNET
from helpers.report import header
from helpers.scans import SCANNET_JUDGES
from noc import majority, score

from jointseg.adapt.head import AdaptParams
from jointseg.adapt.learn import Corrected, adapt
from jointseg.io import read_scan, write_scan
from jointseg.labels.version import version_scan
from jointseg.pipeline import load_predictor, run
from jointseg.pipeline.config import PipelineConfig
from jointseg.pipeline.outputs import annotate
from jointseg.scan import Scan
from jointseg.training.data import stable_order

log = logging.getLogger("bench.adapt")


@dataclass
class Ran:
    """A scan's bundled run: the result scan (as written), the segments, the fused labels,
    the transform to the work frame and the fused mIoU."""

    scan: Scan
    result: Scan
    segments: np.ndarray
    fused: np.ndarray
    to_work: np.ndarray
    fused_miou: float


def run_scan(scan: Scan, cfg: PipelineConfig, predictor: Any) -> Ran:
    assert scan.labels is not None, "the bench's scans are labelled"
    res = run(scan, cfg, predictor=predictor)
    to_work = np.eye(4) if res.frame is None else np.asarray(res.frame.matrix(), np.float64)
    fused = res.fusion.labels.astype(np.int64)
    return Ran(scan, annotate(scan, res), res.geometry.segments.astype(np.int64), fused,
               to_work, score(scan.labels, fused))  # fmt: skip


def corrections(ran: Ran, clicks: int) -> np.ndarray:
    """The user's classes after ``clicks`` segment clicks: the segments with the most wrongly
    labelled points each given their majority true class; -1 elsewhere."""
    gt, seg = ran.scan.labels, ran.segments
    assert gt is not None
    n = int(seg.max()) + 1
    wrong = np.bincount(seg[(gt >= 0) & (gt != ran.fused) & (seg >= 0)], minlength=n)
    best = majority(seg, gt, n)
    order = [s for s in np.argsort(-wrong, kind="stable") if wrong[s] > 0 and best[s] >= 0]
    user = np.full(len(gt), -1, np.int16)
    chosen = np.zeros(n, bool)
    chosen[order[:clicks]] = True
    inside = (seg >= 0) & chosen[np.maximum(seg, 0)]
    user[inside] = best[seg[inside]]
    return user


def adapted_model(ran: Ran, clicks: int, params: AdaptParams, folder: Path, name: str,
                  predictor: Any, cfg: PipelineConfig) -> tuple[Path, float]:  # fmt: skip
    """Correct, save the version, adapt; the model's path and the seconds adapt took."""
    path = folder / f"{name}_v1.ply"
    write_scan(version_scan(ran.result, corrections(ran, clicks)), path)
    t = time.perf_counter()
    out = folder / f"{name}.pt"
    adapt([Corrected(path, name, 1, ran.to_work)], out, predictor=predictor,
          choice=cfg.network.choice(), params=params)  # fmt: skip
    return out, time.perf_counter() - t


def judge(model: Path, scans: dict[str, Ran], names: list[str], seed: int) -> dict[str, float]:
    cfg = PipelineConfig.model_validate({"seed": seed, "network": {"weights": str(model)}})
    predictor = load_predictor(cfg.network)
    return {n: run_scan(scans[n].scan, cfg, predictor).fused_miou for n in names}


def room(name: str) -> str:
    return name.rsplit("_", 1)[0] if name.startswith("scene") else name


def table(rows: list[tuple[str, str, str, int, float, float, float]]) -> None:
    print("| corrected scan | split | judged on | scans | bundled | adapted | gain (points) |")
    print("|---|---|---|---|---|---|---|")
    for corrected, split, what, n, before, after, _ in rows:
        print(f"| {corrected} | {split} | {what} | {n} | {before:.3f} | {after:.3f} | "
              f"{100 * (after - before):+.1f} |")  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clicks", type=int, default=20)
    p.add_argument("--datasets", default="scannet,s3dis")
    p.add_argument("--steps", type=int, default=AdaptParams().steps)
    p.add_argument("--keep-weight", type=float, default=AdaptParams().keep_weight)
    p.add_argument("--lr", type=float, default=AdaptParams().lr)
    p.add_argument("--layers", type=int, default=AdaptParams().layers)
    p.add_argument("--corrected-share", type=float, default=AdaptParams().corrected_share)
    p.add_argument("--replay-rooms", type=int, default=AdaptParams().replay_rooms)
    p.add_argument("--keep-base-above", type=float, default=AdaptParams().keep_base_above)
    p.add_argument("--min-base-probability", type=float, default=AdaptParams().min_base_probability)
    p.add_argument("--s3dis-rooms", type=int, default=3)
    p.add_argument(
        "--s3dis-judged",
        choices=("judging", "tuning"),
        default="judging",
        help="judge the S3DIS models on the judging rooms, or on 6 other tuning rooms (to "
        "choose settings without looking at the judging rooms)",
    )
    p.add_argument(
        "--timing",
        type=int,
        default=0,
        help="only time one adaptation over this many corrected ScanNet scans (the 10-minute "
        "budget for 10 scans), as `jointseg adapt` runs it",
    )
    p.add_argument("--only-split", choices=("tuning", "judging", "all"), default="all")
    args = p.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if not SCANNET.is_dir():
        sys.exit(f"{SCANNET}: the real scans are missing (../shared/data)")
    params = AdaptParams(
        steps=args.steps,
        keep_weight=args.keep_weight,
        lr=args.lr,
        layers=args.layers,
        corrected_share=args.corrected_share,
        replay_rooms=args.replay_rooms,
        keep_base_above=args.keep_base_above,
        min_base_probability=args.min_base_probability,
    )
    if args.timing:
        timing(args.timing, args.clicks, params)
        return
    header("Learning from corrections: adapted model against the bundled network")
    print(f"settings: {args.clicks} clicks, {params.model_dump()}\n")
    cfg = PipelineConfig(seed=0)
    predictor = load_predictor(cfg.network)
    rows: list[tuple[str, str, str, int, float, float, float]] = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        if "scannet" in args.datasets:
            rows += scannet(folder, args, params, cfg, predictor)
        if "s3dis" in args.datasets:
            rows += s3dis(folder, args, params, cfg, predictor)
    table(rows)
    print()
    print("| split | judged on | pairs | mean gain (points) | adapt seconds (mean) |")
    print("|---|---|---|---|---|")
    for split in ("tuning", "judging"):
        for what in ("re-scans", "other ScanNet rooms", "S3DIS judging rooms",
                     "S3DIS tuning rooms"):  # fmt: skip
            sel = [r for r in rows if r[1] == split and r[2] == what]
            if sel:
                gain = statistics.mean(100 * (r[5] - r[4]) for r in sel)
                secs = statistics.mean(r[6] for r in sel)
                print(f"| {split} | {what} | {len(sel)} | {gain:+.1f} | {secs:.1f} |")


def timing(count: int, clicks: int, params: AdaptParams) -> None:
    """Seconds of one `jointseg adapt` over ``count`` corrected ScanNet scans, in a fresh
    process as a user runs it (the scans corrected and saved first, untimed)."""
    import subprocess

    header(f"Learning from corrections: one adaptation over {count} corrected scans")
    cfg = PipelineConfig(seed=0)
    predictor = load_predictor(cfg.network)
    names = sorted(_load(SCANNET))[:count]
    with tempfile.TemporaryDirectory() as tmp:
        folder, paths = Path(tmp), []
        for name in names:
            ran = run_scan(read_scan(SCANNET / f"{name}.ply"), cfg, predictor)
            paths.append(folder / f"{name}_v1.ply")
            write_scan(version_scan(ran.result, corrections(ran, clicks)), paths[-1])
        t = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "jointseg", "adapt", *map(str, paths), "-o",
             str(folder / "site.pt"), "--steps", str(params.steps)],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        seconds = time.perf_counter() - t
    if done.returncode:
        sys.exit(done.stderr[-2000:])
    points = sum(read_scan(SCANNET / f"{n}.ply").xyz.shape[0] for n in names)
    print("| scans | points | `jointseg adapt` wall seconds (whole process) | budget |")
    print("|---|---|---|---|")
    print(f"| {count} | {points:,} | {seconds:.1f} | 600 |")


def _load(folder: Path) -> dict[str, Scan]:
    return {f.stem: read_scan(f) for f in sorted(folder.glob("*.ply"))}


def scannet(folder: Path, args: argparse.Namespace, params: AdaptParams, cfg: PipelineConfig,
            predictor: Any) -> list[tuple[str, str, str, int, float, float, float]]:  # fmt: skip
    scans = {n: run_scan(s, cfg, predictor) for n, s in _load(SCANNET).items()}
    by_room: dict[str, list[str]] = {}
    for n in sorted(scans):
        by_room.setdefault(room(n), []).append(n)
    rows = []
    for r, names in by_room.items():
        split = "judging" if r in SCANNET_JUDGES else "tuning"
        if len(names) < 2 or args.only_split not in ("all", split):
            continue
        first, again = names[0], names[1:]
        model, secs = adapted_model(scans[first], args.clicks, params, folder, first,
                                    predictor, cfg)  # fmt: skip
        others = [n for n in scans if room(n) != r]
        after = judge(model, scans, again + others, cfg.seed)
        for what, sel in (("re-scans", again), ("other ScanNet rooms", others)):
            before = statistics.mean(scans[n].fused_miou for n in sel)
            rows.append((first, split, what, len(sel), before,
                         statistics.mean(after[n] for n in sel), secs))  # fmt: skip
        print(f"{first}: adapted in {secs:.1f} s; re-scans "
              f"{[round(scans[n].fused_miou, 3) for n in again]} -> "
              f"{[round(after[n], 3) for n in again]}", flush=True)  # fmt: skip
    return rows


def s3dis(folder: Path, args: argparse.Namespace, params: AdaptParams, cfg: PipelineConfig,
          predictor: Any) -> list[tuple[str, str, str, int, float, float, float]]:  # fmt: skip
    all_scans = _load(AREA6)
    order = stable_order(sorted(all_scans))
    judging, tuning = order[:10], order[10:]
    corrected = tuning[: args.s3dis_rooms]
    if args.s3dis_judged == "tuning":
        judging = tuning[args.s3dis_rooms : args.s3dis_rooms + 6]
    what = f"S3DIS {args.s3dis_judged} rooms"
    scans = {n: run_scan(all_scans[n], cfg, predictor) for n in judging + corrected}
    rows = []
    for first in corrected:
        model, secs = adapted_model(scans[first], args.clicks, params, folder, first,
                                    predictor, cfg)  # fmt: skip
        after = judge(model, scans, judging, cfg.seed)
        before = statistics.mean(scans[n].fused_miou for n in judging)
        rows.append((first, "tuning", what, len(judging), before,
                     statistics.mean(after.values()), secs))  # fmt: skip
        print(f"{first}: adapted in {secs:.1f} s; {what} {before:.3f} -> "
              f"{statistics.mean(after.values()):.3f}", flush=True)  # fmt: skip
    return rows


if __name__ == "__main__":
    main()
