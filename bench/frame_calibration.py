"""Is the frame stage's confidence in its up axis worth its number (issue 63, point 2)?

Every tuning and judging room (S3DIS Area_6, ScanNet, and the S3DIS fragment from another
building), delivered every way a user delivers it, goes through the frame stage's up decision
as the pipeline makes it: the file's word, the capture and the geometry weighed, and the
pipeline's network (the colour-free one for a scan without colour) judging the likeliest
candidates whenever ``weigh.needs_judge`` asks it. Deliveries: those of
``jointseg.fitting.up_axis_cases`` (z up as is and as LAS, y up as a plain export, a GLB and a phone
app's PLY, upside down, x up, tilted 5-20 degrees, a 1.2 m floor slice, a wall-side half room,
``--views`` camera frames) and five more of ``bench/helpers/deliveries.py`` (no colour, z up and
y up; millimetres, y up; international feet; 0.3 % stray points).

Tuning rooms are those of the up-axis fit plan (``fit/up_axis.json``, what ``up_model.json``
and its calibration were fitted on); every other room, and the fragment, is judging.

Per split: a reliability table (confidence bins x decisions x share right), how many decisions
turned a scan away from its file's own axis and how many of those were wrong, then every wrong
call with its confidence and whether the frame stage warned. The evidence and the network's
verdicts are cached under ``bench/_cache/frame_calibration`` (a rerun takes seconds); the
decision and its warnings are recomputed each run by the library's own functions
(``weigh.weigh``, ``decide.up_warnings``), and ``--check N`` runs ``decide_frame`` itself on N
cases to show that it decides the same.

    nice .venv/bin/python bench/frame_calibration.py [--views 2] [--check 5] [--cached-only]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from helpers.deliveries import deliver, feet, millimetres, no_colour, strays, y_up
from helpers.inputs import AREA6, BENCH, CACHE, FRAGMENT, SCANNET
from helpers.report import header

from jointseg.fitting.scans import scan_files
from jointseg.fitting.up_axis import read_plan
from jointseg.fitting.up_axis_cases import (
    DELIVERIES,
    Case,
    evidence_record,
    room_cases,
    verdict_record,
)
from jointseg.frame import gravity, weigh
from jointseg.frame.colour import decide_colour
from jointseg.frame.decide import decide_frame, gather, judge_candidates, up_warnings
from jointseg.frame.model import MODEL_FILE
from jointseg.frame.params import FrameParams
from jointseg.frame.sources import SIGNED_AXES
from jointseg.io import read_scan
from jointseg.labeller import LabelFn
from jointseg.scan import Scan

log = logging.getLogger("frame_calibration")

PLAN = BENCH.parent / "fit" / "up_axis.json"
#: Part of every cached case's key: bump it when what is gathered changes.
VERSION = 3
#: Reliability bins of the stated confidence.
EDGES = (0.0, 0.5, 0.7, 0.8, 0.9, 0.95, 1.0001)
#: Deliveries made here beyond up_axis_cases's: (name, truth, steps of helpers.deliveries).
EXTRA: tuple[tuple[str, str, tuple[Any, ...]], ...] = (
    ("z up, no colour", "+z", (no_colour,)),
    ("y up, no colour", "+y", (y_up, no_colour)),
    ("y up, millimetres", "+y", (y_up, millimetres)),
    ("z up, feet", "+z", (feet,)),
    ("z up, stray points", "+z", (strays,)),
)
#: The deliveries run by default (``--all``: every one of up_axis_cases and EXTRA): the judging
#: network costs seconds a case on a shared CPU, so the LAS, GLB and phone-app deliveries
#: (whose file says its axis strongly) and two of the extra ones are left to ``--all``.
DEFAULT = (
    "z up, as is", "y up export", "upside down", "x up", "z up, tilted", "z up, 1.2 m slice",
    "z up, half room", "z up, no colour", "y up, millimetres", "z up, stray points",
)  # fmt: skip


@dataclass
class Row:
    """One case as gathered: the evidence before the network and the verdicts it gave."""

    case: Case
    split: str
    evidence: weigh.Evidence
    judged: dict[str, np.ndarray]
    seconds: float


def extra_cases(name: str, source: str, room: Scan, kinds: tuple[str, ...]) -> list[Case]:
    """The deliveries of :data:`EXTRA` named in ``kinds`` of one z-up room (its own
    generator)."""
    rng = np.random.default_rng([11, zlib.crc32(name.encode())])
    out = []
    for delivery, truth, steps in EXTRA:
        if delivery not in kinds:
            continue
        d = deliver(steps, room.xyz, room.rgb, rng)
        scan = Scan(d.xyz, d.rgb, None, source_format="ply")
        out.append(Case(name, source, delivery, truth, scan))
    return out


def all_cases(views: int, kinds: tuple[str, ...]) -> list[tuple[str, Case]]:
    """(split, case) of every room and delivery: the plan's rooms tuning, the rest judging."""
    plan = read_plan(PLAN)
    tuned = {p.stem for p in scan_files([PLAN.parent / r for r in plan.rooms])}
    out = []
    for path in [*scan_files([AREA6, SCANNET]), FRAGMENT]:
        room = read_scan(path)
        room = Scan(room.xyz, room.rgb, None, source_format="ply")
        source = {"s3dis_area6": "S3DIS", "scannet": "ScanNet"}.get(path.parent.name, "fragment")
        split = "tuning" if path.stem in tuned else "judging"
        cases = room_cases(path.stem, source, room, seed=0, kinds=kinds, n_views=views)
        cases += extra_cases(path.stem, source, room, kinds)
        out += [(split, c) for c in cases]
    return out


def interleaved(cases: list[tuple[str, Case]]) -> list[tuple[str, Case]]:
    """The rooms taken in turn from each source (the fragment first), so that a gathering cut
    short has covered every source."""
    by_source: dict[str, list[list[tuple[str, Case]]]] = {}
    rooms: dict[str, list[tuple[str, Case]]] = {}
    for sc in cases:
        rooms.setdefault(sc[1].name, []).append(sc)
    for room in rooms.values():
        by_source.setdefault(room[0][1].source, []).append(room)
    queues = sorted(by_source.values(), key=lambda q: len(q))
    out: list[tuple[str, Case]] = []
    for i in range(max(len(q) for q in queues)):
        for q in queues:
            out += q[i] if i < len(q) else []
    return out


def _key(case: Case) -> str:
    h = hashlib.sha256(f"{VERSION}|{case.scan.source_format}|".encode())
    h.update(json.dumps(case.scan.meta, sort_keys=True, default=str).encode())
    h.update(MODEL_FILE.read_bytes())
    for a in (case.scan.xyz, case.scan.rgb):
        h.update(b"none" if a is None else np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:32]


def _gather_now(case: Case, judge_for: Callable[[bool], LabelFn | None]) -> dict[str, Any]:
    """What decide_up gathers on one case, and the verdicts of the pipeline's network on the
    candidates it would be asked about (none when it is not asked)."""
    scan, params = case.scan, FrameParams()
    xyz = scan.xyz
    centre = np.median(xyz[:: max(1, len(xyz) // 100_000)], axis=0)
    sample = gravity.frame_sample(xyz - centre, np.random.default_rng(0))
    g = gather(scan, sample, params)
    colour = decide_colour(scan.rgb, params.colour)
    judged: dict[str, np.ndarray] = {}
    judge = judge_for(colour.usable)
    if judge is not None and weigh.needs_judge(g.evidence):
        names = weigh.candidates(g.evidence)
        judged = judge_candidates(g, scan, centre, colour, judge, names)
    return {**evidence_record(g.evidence), "judged": verdict_record(judged)}


def pipeline_judge() -> Callable[[bool], LabelFn | None]:
    """The pipeline's judge for a scan with or without usable colour (loaded on first use)."""
    from jointseg.network.choice import network_for
    from jointseg.network.judge import crop_labeller
    from jointseg.pipeline import PipelineConfig, load_predictor

    config = PipelineConfig()
    loaded: dict[object, Any] = {}

    def judge_for(usable: bool) -> LabelFn | None:
        if "predictor" not in loaded:
            loaded["predictor"] = load_predictor(config.network)
        if usable not in loaded:
            chosen = network_for(loaded["predictor"], config.network.choice(), usable)
            loaded[usable] = crop_labeller(chosen)
        return loaded[usable]

    return judge_for


def gather_rows(cases: list[tuple[str, Case]], cache: Path) -> list[Row]:
    """Every case's evidence and verdicts, from ``cache`` or gathered now and stored."""
    judge_for = pipeline_judge()
    rows = []
    for n, (split, case) in enumerate(cases):
        path = cache / f"{_key(case)}.json"
        t = time.perf_counter()
        if path.is_file():
            body = json.loads(path.read_text())
        else:
            body = _gather_now(case, judge_for)
            body["seconds"] = time.perf_counter() - t
            path.parent.mkdir(parents=True, exist_ok=True)
            path.with_suffix(".tmp").write_text(json.dumps(body))
            path.with_suffix(".tmp").replace(path)
            log.info("%d/%d %s %s: %.1f s", n + 1, len(cases), case.name, case.delivery,
                     body["seconds"])  # fmt: skip
        evidence = weigh.Evidence(
            np.array(body["file"]), np.array(body["axis_p"]), np.array(body["sign_p"]),
            bool(body["room_like"]), body["camera_up"], np.array(body["floor_only"]),
        )  # fmt: skip
        judged = {a: np.array(v) for a, v in body["judged"].items()}
        rows.append(Row(case, split, evidence, judged, float(body["seconds"])))
    return rows


@dataclass(frozen=True)
class Call:
    """The frame stage's up decision on one row, as decide_frame makes and reports it."""

    axis: str
    confidence: float
    probability: float
    turned: bool
    warned: bool


def call(row: Row) -> Call:
    """The decision, calibrated confidence and warnings the library gives on ``row``."""
    w = weigh.weigh(row.evidence, row.judged)
    axis, conf = w.best, w.confidence
    estimate = gravity.UpEstimate(gravity.AXES[axis], axis, 0.0, conf, {})
    warned = bool(up_warnings(estimate, w.file_axis, w.floor_elsewhere))
    return Call(axis, conf, w.probability, w.turned, warned)


def reliability(rows: list[Row], split: str) -> None:
    """Confidence bins x decisions x share right, and the turns, of one split."""
    part = [(r, call(r)) for r in rows if r.split == split]
    print(f"\n{split}: {len(part)} decisions, {len({r.case.name for r, _ in part})} rooms\n")
    print("| stated confidence | decisions | right | share right | warned |")
    print("|---|---|---|---|---|")
    for lo, hi in zip(EDGES[:-1], EDGES[1:], strict=True):
        sel = [(r, c) for r, c in part if lo <= c.confidence < hi]
        right = sum(c.axis == r.case.truth for r, c in sel)
        share = f"{right / len(sel):.3f}" if sel else "-"
        warned = sum(c.warned for _, c in sel)
        print(f"| {lo:.2f}-{min(hi, 1.0):.2f} | {len(sel)} | {right} | {share} | {warned} |")
    turned = [(r, c) for r, c in part if c.turned]
    bad = sum(c.axis != r.case.truth for r, c in turned)
    kept_wrong = sum(c.axis != r.case.truth for r, c in part if not c.turned)
    print(f"\nturned from the file's axis: {len(turned)} (wrong {bad}); kept wrong: {kept_wrong}")
    wrong = [(r, c) for r, c in part if c.axis != r.case.truth]
    silent = sum(not c.warned for _, c in wrong)
    print(f"wrong calls: {len(wrong)}, of them silent (no warning): {silent}\n")
    if wrong:
        print("| scan | delivery | truth | decided | turned | confidence | p | warned |")
        print("|---|---|---|---|---|---|---|---|")
    for r, c in wrong:
        print(f"| {r.case.name} | {r.case.delivery} | {r.case.truth} | {c.axis} | "
              f"{'yes' if c.turned else 'no'} | {c.confidence:.3f} | {c.probability:.3f} | "
              f"{'yes' if c.warned else '**no**'} |")  # fmt: skip


def keep_needed(rows: list[Row]) -> None:
    """On the tuning deliveries whose file's axis is right: the most probable other axis, and
    its opposite (the least :data:`weigh.KEEP` and ``KEEP_UPSIDE_DOWN`` keeping them all)."""
    side, opposite = 0.0, 0.0
    for r in rows:
        w = weigh.weigh(r.evidence, r.judged)
        own = w.file_axis
        if r.split != "tuning" or own is None or own != r.case.truth:
            continue
        for i, a in enumerate(SIGNED_AXES):
            if a == own:
                continue
            if a[1] == own[1]:
                opposite = max(opposite, float(w.p[i]))
            else:
                side = max(side, float(w.p[i]))
    keep = f"KEEP {weigh.KEEP}, KEEP_UPSIDE_DOWN {weigh.KEEP_UPSIDE_DOWN}"
    print(f"\ntuning, file's axis right: most probable other axis {side:.3f}, its opposite "
          f"{opposite:.3f} ({keep})")  # fmt: skip


def check(rows: list[Row], n: int) -> None:
    """decide_frame itself, with the pipeline's judge, on ``n`` cases the network judged:
    the same axis and confidence as the cached replay."""
    judge_for = pipeline_judge()
    for r in [r for r in rows if r.judged][:n]:
        colour = decide_colour(r.case.scan.rgb, True)
        frame = decide_frame(r.case.scan, FrameParams(), judge=judge_for(colour.usable))
        c = call(r)
        same = frame.up.axis == c.axis and abs(frame.up.confidence - c.confidence) < 1e-9
        print(f"check {r.case.name} {r.case.delivery}: decide_frame {frame.up.axis} "
              f"{frame.up.confidence:.4f}, replay {c.axis} {c.confidence:.4f}: "
              f"{'same' if same else 'DIFFERENT'}")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--views", type=int, default=1, help="camera frames cut from every room")
    ap.add_argument("--all", action="store_true", help="every delivery, not only DEFAULT's")
    ap.add_argument("--splits", default="judging,tuning")
    ap.add_argument("--cache", type=Path, default=CACHE / "frame_calibration")
    ap.add_argument("--gather-only", action="store_true", help="fill the cache, print nothing")
    ap.add_argument("--cached-only", action="store_true", help="only the cases in the cache")
    ap.add_argument("--check", type=int, default=0, help="decide_frame itself on N cases")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    log.setLevel(logging.INFO)
    kinds = DELIVERIES + tuple(e[0] for e in EXTRA) if args.all else DEFAULT
    splits = args.splits.split(",")
    cases = interleaved([c for c in all_cases(args.views, kinds) if c[0] in splits])
    if args.cached_only:
        cases = [c for c in cases if (args.cache / f"{_key(c[1])}.json").is_file()]
    if not args.gather_only:
        header("the frame stage's up: stated confidence against the share right")
    rows = gather_rows(cases, args.cache)
    if args.gather_only:
        return
    for split in splits:
        reliability(rows, split)
    keep_needed(rows)
    check(rows, args.check)


if __name__ == "__main__":
    main()
