"""Clicks a user needs to correct the fused labels (issue 63): NoC@80, as interactive
segmentation papers report it.

A simulated user corrects the shipped pipeline's fused labels one click at a time. A click is
one edit ``{"segments": [id], "label": class}`` applied through the library's own correction
path (jointseg.labels.edits: ``parse_edits``, ``apply_edits``, ``version_labels``), which the
service and ``jointseg relabel`` use. The clicked segment gets the majority true class of its
points; which segment is clicked (``--pick``):

- ``gain`` (default): the one whose click makes the most points right. A segment mixing classes
  that the network already labels point by point is left alone, as a user would leave it;
- ``wrong``: the one with the most wrongly labelled points (truth labelled and not the current
  label) among those a click would change, the issue's rule taken literally. Such a click can
  make the right points of a segment's minority classes wrong.

Clicks go on until the scan's mIoU reaches the highest threshold (and at least 20 clicks are
made), ``--cap`` clicks, or no click helps.

The fused labels are the pipeline's defaults, run as bench/structure.py runs them ("after"):
the scan levelled by the frame stage with the up axis forced to +z, the bundled RandLA-Net
(seed 0) and the default geometry (both cached under bench/_cache), fused with
``FusionParams()`` defaults, the main planes and the structure reading. mIoU is
bench/structure.py's: over the classes present in the truth, unlabelled points (-1) ignored.

Per scan: fused mIoU; the oracle's (every segment its majority true class, as
bench/fusion_real.py's); the ceiling of ``gain`` clicks (every segment whose click helps its
majority class, the others as fused: the most clicks on whole segments can reach); clicks to
0.80 / 0.85 / 0.90 ("-" where the clicks stopped below, ">cap" where the cap came first); mIoU
after 5, 10 and 20 clicks; the points the clicks changed until 0.80 (what a per-point annotator
would touch; all the clicks' where 0.80 is not reached) and per click. Pooled per dataset and
split: mean NoC (a scan that does not reach it counts as the cap) and the share of scans
reaching each threshold within the cap. ``--cli`` checks the fused labels against
``jointseg segment`` with defaults on named scans (its ``segment`` and ``fused_label`` fields):
the share of points with the same fused label, and NoC@80 on both.

    .venv/bin/python bench/noc.py [--scans judging|tuning|all] [--datasets scannet,s3dis]
        [--cap 200] [--pick gain|wrong] [--cli scene0005_00,area6_office_1]
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from helpers.inputs import AREA6, SCANNET
from helpers.report import header
from helpers.scans import Item, geometry_output, load_items, network_output, structure_hint
from real_world import JOINTSEG, child_env
from structure import levelled, miou

from jointseg.adapt.spread import propose
from jointseg.classes import NUM_CLASSES
from jointseg.fusion import FusionParams, fuse
from jointseg.io import read_scan
from jointseg.labels.edits import apply_edits, parse_edits, version_labels
from jointseg.metrics import confusion_matrix
from jointseg.pipeline import load_predictor
from jointseg.pipeline.config import PipelineConfig
from jointseg.scan import Scan

THRESHOLDS = (0.80, 0.85, 0.90)
#: Clicks after which the mIoU is reported.
AFTER = (5, 10, 20)
DATASETS = {"scannet": SCANNET, "s3dis": AREA6}
SPLITS = {"judging": ("judge",), "tuning": ("tune",), "all": ("judge", "tune")}


@dataclass
class Run:
    """One scan's simulated corrections."""

    scan: str
    dataset: str
    split: str
    points: int
    segments: int
    fused: float
    oracle: float
    ceiling: float
    curve: list[float] = field(default_factory=list)  # mIoU after 0, 1, 2, ... clicks
    changed: list[int] = field(default_factory=list)  # points changed by click 1, 2, ...

    def noc(self, threshold: float) -> int | None:
        """Clicks to reach ``threshold`` (0 when the fused labels do), None when never."""
        return next((k for k, v in enumerate(self.curve) if v >= threshold), None)

    def after(self, clicks: int) -> float:
        """mIoU after ``clicks`` clicks (the last one when the user stopped earlier)."""
        return self.curve[min(clicks, len(self.curve) - 1)]

    def points_to(self, threshold: float) -> int:
        """Points the clicks changed until ``threshold`` (all clicks' when never reached)."""
        k = self.noc(threshold)
        return int(sum(self.changed[: len(self.changed) if k is None else k]))


def score(gt: np.ndarray, labels: np.ndarray) -> float:
    """mIoU over the classes present in the truth, unlabelled points ignored."""
    keep = gt >= 0
    return miou(confusion_matrix(gt[keep], labels[keep]))


def fused_labels(item: Item, spec: str, predictors: dict) -> tuple[np.ndarray, np.ndarray]:
    """Segments and fused labels with the pipeline's defaults (as bench/structure.py's
    "after")."""
    labels, probs = network_output(spec, item, predictors)
    g = geometry_output("default", item)
    seg = g["segments"].astype(np.int64)
    out = fuse(item.scan.xyz, seg, labels, probs, FusionParams(), main_plane=g["plane_id"] >= 0,
               structure=structure_hint(g), has_colour=item.scan.rgb is not None)  # fmt: skip
    return seg, out.labels.astype(np.int64)


def majority(seg: np.ndarray, gt: np.ndarray, n_segments: int) -> np.ndarray:
    """Each segment's majority true class (-1 for a segment without labelled points)."""
    keep = (gt >= 0) & (seg >= 0)
    flat = np.bincount(seg[keep] * NUM_CLASSES + gt[keep], minlength=n_segments * NUM_CLASSES)
    counts = flat.reshape(n_segments, NUM_CLASSES)
    return np.where(counts.sum(1) > 0, counts.argmax(1), -1)


def gains(seg: np.ndarray, gt: np.ndarray, current: np.ndarray, best: np.ndarray) -> np.ndarray:
    """Per segment: right points after a click giving it ``best`` minus right points now (0 for
    a segment without labelled points)."""
    n = len(best)
    inside = (seg >= 0) & (gt >= 0)
    s = np.where(inside, seg, 0)
    now = np.bincount(s[inside & (current == gt)], minlength=n)
    after = np.bincount(s[inside & (gt == best[s])], minlength=n)
    return np.where(best >= 0, after - now, 0)


def next_click(
    seg: np.ndarray, gt: np.ndarray, current: np.ndarray, best: np.ndarray, pick: str
) -> int:
    """The segment clicked next; -1 when no click would help.

    ``gain``: the segment whose click makes the most points right (none when no click gains).
    ``wrong``: the segment with the most wrong points among those a click would change, even
    when the click makes right points of other classes wrong (the issue's rule, literally)."""
    n = len(best)
    if pick == "gain":
        counts = gains(seg, gt, current, best)
    else:
        inside = seg >= 0
        s = np.where(inside, seg, 0)
        counts = np.bincount(s[inside & (gt >= 0) & (current != gt)], minlength=n)
        differs = np.bincount(s[inside & (current != best[s])], minlength=n) > 0
        counts = np.where(differs & (best >= 0), counts, 0)
    top = int(counts.argmax()) if n else 0
    return top if n and counts[top] > 0 else -1


def accept_proposal(item: Item, seg: np.ndarray, fused: np.ndarray, user: np.ndarray,
                    predictor: Any) -> tuple[np.ndarray, int]:  # fmt: skip
    """The user accepts what their corrections so far propose for the rest of the scan
    (jointseg.adapt.spread, as the viewer offers it): the user classes after, points changed."""
    result = Scan(item.scan.xyz, item.scan.rgb).with_fields(
        segment=seg.astype(np.int32), fused_label=fused.astype(np.int32), user_label=user
    )
    proposal = propose(result, predictor, to_work=np.eye(4))  # the bench's scans are levelled
    if not len(proposal.segments):
        return user, 0
    outcome = apply_edits(parse_edits({"edits": proposal.edits()}), machine_labels=fused,
                          user_label=user, segment=seg, xyz=item.scan.xyz)  # fmt: skip
    return outcome.user_label, outcome.changed


def simulate(item: Item, seg: np.ndarray, fused: np.ndarray, cap: int, pick: str,
             spread: int = 0, predictor: Any = None) -> Run:  # fmt: skip
    """Click segments, through jointseg.labels.edits, until the highest threshold (and the last
    click reported) or ``cap`` clicks, or no click helps. With ``spread``, after every
    ``spread`` clicks the user accepts the proposal of their corrections (one more click)."""
    gt = item.scan.labels
    assert gt is not None
    gt = gt.astype(np.int64)
    n_segments = int(seg.max()) + 1
    best = majority(seg, gt, n_segments)
    s = np.maximum(seg, 0)
    oracle = np.where((seg >= 0) & (best[s] >= 0), best[s], fused)
    helped = (seg >= 0) & (gains(seg, gt, fused, best) > 0)[s]
    ceiling = np.where(helped, best[s], fused)
    run = Run(item.name, item.dataset, item.split, len(gt), n_segments, score(gt, fused),
              score(gt, oracle), score(gt, ceiling))  # fmt: skip
    run.curve.append(run.fused)
    user: np.ndarray | None = None
    current = version_labels(fused, user)
    while len(run.changed) < cap and (
        run.curve[-1] < THRESHOLDS[-1] or len(run.changed) < AFTER[-1]
    ):
        target = next_click(seg, gt, current, best, pick)
        if target < 0:
            break
        edits = parse_edits({"edits": [{"segments": [target], "label": int(best[target])}]})
        outcome = apply_edits(edits, machine_labels=fused, user_label=user, segment=seg,
                              xyz=item.scan.xyz)  # fmt: skip
        user = outcome.user_label
        current = version_labels(fused, user)
        run.changed.append(outcome.changed)
        run.curve.append(score(gt, current))
        if spread and user is not None and len(run.changed) % (spread + 1) == spread:
            user, changed = accept_proposal(item, seg, fused, user, predictor)
            current = version_labels(fused, user)
            run.changed.append(changed)
            run.curve.append(score(gt, current))
    return run


def noc_cell(run: Run, threshold: float, cap: int) -> str:
    """Clicks to ``threshold``; "-" where the clicks stopped below it (no click helped),
    ">cap" where the cap came first."""
    k = run.noc(threshold)
    if k is not None:
        return str(k)
    return f">{cap}" if len(run.changed) >= cap else "-"


def scan_table(runs: list[Run], cap: int) -> None:
    """One row per scan."""
    noc = " | ".join(f"NoC@{round(100 * t)}" for t in THRESHOLDS)
    after = " | ".join(f"mIoU@{k}" for k in AFTER)
    print(f"| scan | split | points | segments | fused mIoU | oracle | ceiling | {noc} | {after} "
          "| points changed to 0.80 | points per click |")  # fmt: skip
    print("|---" * (9 + len(THRESHOLDS) + len(AFTER)) + "|")
    for r in runs:
        k = r.noc(THRESHOLDS[0])
        clicks = len(r.changed) if k is None else k
        per = f"{r.points_to(THRESHOLDS[0]) / clicks:.0f}" if clicks else "-"
        nocs = " | ".join(noc_cell(r, t, cap) for t in THRESHOLDS)
        afters = " | ".join(f"{r.after(c):.3f}" for c in AFTER)
        print(
            f"| {r.scan} | {r.split} | {r.points} | {r.segments} | {r.fused:.3f} | "
            f"{r.oracle:.3f} | {r.ceiling:.3f} | {nocs} | {afters} | "
            f"{r.points_to(THRESHOLDS[0])} | {per} |"
        )


def pooled_table(runs: list[Run], cap: int) -> None:
    """Mean per dataset and split: a scan that does not reach a threshold counts as the cap."""
    noc = " | ".join(f"mean NoC@{round(100 * t)} | reached" for t in THRESHOLDS)
    after = " | ".join(f"mIoU@{k}" for k in AFTER)
    print(f"| dataset | split | scans | fused mIoU | oracle | ceiling | {noc} | {after} "
          "| points changed to 0.80 |")  # fmt: skip
    print("|---" * (7 + 2 * len(THRESHOLDS) + len(AFTER)) + "|")
    groups: dict[tuple[str, str], list[Run]] = {}
    for r in runs:
        groups.setdefault((r.dataset, r.split), []).append(r)
    for (dataset, split), group in sorted(groups.items()):
        cells = []
        for t in THRESHOLDS:
            clicks = [cap if (n := r.noc(t)) is None else n for r in group]
            reached = sum(r.noc(t) is not None for r in group)
            cells.append(f"{np.mean(clicks):.1f} | {reached}/{len(group)}")
        afters = " | ".join(f"{np.mean([r.after(c) for r in group]):.3f}" for c in AFTER)
        points = np.mean([r.points_to(THRESHOLDS[0]) for r in group])
        print(f"| {dataset} | {split} | {len(group)} | {np.mean([r.fused for r in group]):.3f} | "
              f"{np.mean([r.oracle for r in group]):.3f} | "
              f"{np.mean([r.ceiling for r in group]):.3f} | {' | '.join(cells)} | {afters} | "
              f"{points:.0f} |")  # fmt: skip


def cli_check(
    items: list[Item], runs: list[Run], fused: dict[str, np.ndarray], cap: int, pick: str
) -> None:
    """The bench's fused labels against ``jointseg segment``'s with defaults, and NoC@80 on
    both, for each of ``items`` (scans read from their files)."""
    print("\n### The bench's fused labels against `jointseg segment`\n")
    print("| scan | same fused label | fused mIoU bench / CLI | oracle bench / CLI "
          "| NoC@80 bench / CLI |")  # fmt: skip
    print("|---|---|---|---|---|")
    by_name = {r.scan: r for r in runs}
    for item in items:
        path = next(p for p in (SCANNET, AREA6) if (p / f"{item.name}.ply").is_file())
        with tempfile.TemporaryDirectory() as folder:
            out = Path(folder) / "out.ply"
            cmd = [JOINTSEG, "segment", str(path / f"{item.name}.ply"), "-o", str(out)]
            subprocess.run(cmd, check=True, capture_output=True, env=child_env(1))
            result = read_scan(out)
        seg = np.asarray(result.fields["segment"], np.int64)
        labels = np.asarray(result.fields["fused_label"], np.int64)
        cli = simulate(item, seg, labels, cap, pick)
        mine = by_name[item.name]
        same = float(np.mean(labels == fused[item.name]))
        print(f"| {item.name} | {100 * same:.2f} % | {mine.fused:.3f} / {cli.fused:.3f} | "
              f"{mine.oracle:.3f} / {cli.oracle:.3f} | {noc_cell(mine, THRESHOLDS[0], cap)} / "
              f"{noc_cell(cli, THRESHOLDS[0], cap)} |")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", choices=sorted(SPLITS), default="all")
    parser.add_argument("--datasets", default="scannet,s3dis", help="comma-separated")
    parser.add_argument("--cap", type=int, default=200, help="most clicks per scan")
    parser.add_argument("--judge", type=int, default=10, help="S3DIS judging rooms")
    parser.add_argument("--network", default="randlanet", help="spec; default the bundled one")
    parser.add_argument(
        "--pick",
        choices=("gain", "wrong"),
        default="gain",
        help="the segment clicked: most points made right, or most wrong",
    )
    parser.add_argument(
        "--spread",
        type=int,
        default=0,
        help="accept the corrections' proposal after every N clicks (counted as a click)",
    )
    parser.add_argument("--cli", default="", help="scans to check against `jointseg segment`")
    args = parser.parse_args()
    header("Clicks to correct the fused labels (NoC)")
    logging.basicConfig(level=logging.WARNING)
    print(f"`{Path(sys.argv[0]).name} {' '.join(sys.argv[1:])}`\n")
    folders = [str(DATASETS[d]) for d in args.datasets.split(",")]
    items = [levelled(i) for i in load_items(folders, args.judge, (0, 0, 0))
             if i.split in SPLITS[args.scans]]  # fmt: skip
    predictors: dict = {}
    spread_predictor = load_predictor(PipelineConfig().network) if args.spread else None
    runs, fused = [], {}
    for item in items:
        seg, fused[item.name] = fused_labels(item, args.network, predictors)
        runs.append(simulate(item, seg, fused[item.name], args.cap, args.pick, args.spread,
                             spread_predictor))  # fmt: skip
    runs.sort(key=lambda r: (r.dataset, r.split, r.scan))
    print(f"### Per dataset and split (cap {args.cap} clicks, pick {args.pick})\n")
    pooled_table(runs, args.cap)
    print(f"\n### Per scan (cap {args.cap} clicks, pick {args.pick})\n")
    scan_table(runs, args.cap)
    checked = [i for i in items if i.name in args.cli.split(",")]
    if checked:
        cli_check(checked, runs, fused, args.cap, args.pick)


if __name__ == "__main__":
    main()
