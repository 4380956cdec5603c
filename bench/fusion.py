"""Fusion variants (jointseg.fusion.variants.VARIANTS, the list every fusion benchmark shares)
compared on held-out scans: which mode should be the default?

For every held-out synthetic scan (rooms 5000.. box and L with random yaw, floors 6000..; the
seeds bench/network_accuracy.py uses) and, when present, the real S3DIS fragment, the network
and the geometry run once; then every fusion variant (the paper's rule at several ratio
thresholds, soft votes, the guard, the evidence and learned votes) fuses their outputs. Prints
per-scan mIoU of the network, each variant and the oracle (segment majority of the ground
truth), then a summary per variant: mean mIoU, mean and worst gain over the network, scans where
fusion lost. The winner is the variant with the best mean gain among those that lose on no
scan.

    .venv/bin/python bench/fusion.py [--weights PATH] [--rooms 10] [--floors 2] [--points 300000]
    .venv/bin/python bench/fusion.py --stand-in    # no weights: ground truth with patchy noise
    .venv/bin/python bench/fusion.py --network dgcnn --weights model_1.t7 ... model_6.t7 \
        --rooms 0 --floors 0                       # real weights on the real fragment only

With several weights files every scan is labelled by each of them (one row per scan and
weights); when no synthetic scan is asked for, the summary is over the real ones.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from helpers.inputs import FRAGMENT
from helpers.report import header
from helpers.scans import held_out

from jointseg.fusion import DEFAULT_MODE, FusionParams, fuse
from jointseg.fusion.variants import VARIANTS
from jointseg.geometry import segment
from jointseg.io import read_scan
from jointseg.metrics import evaluate, segment_majority
from jointseg.network import load
from jointseg.network.registry import BACKENDS
from jointseg.pipeline.tables import format_score as fmt
from jointseg.scan import Scan
from jointseg.synth.label_noise import corrupt_labels


@dataclass
class ScanRow:
    name: str
    points: int
    synthetic: bool
    network: float
    oracle: float
    fused: dict[str, float]


def measure(name: str, scan: Scan, labels_probs, seed: int, synthetic: bool) -> ScanRow:
    """Geometry once, then every variant on the same network output."""
    labels, probs = labels_probs
    truth = scan.labels
    assert truth is not None, f"{name} has no labels to score against"
    segments = segment(scan, seed=seed).segments
    fused = {}
    for variant, params in VARIANTS.items():
        result = fuse(scan.xyz, segments, labels, probs, params)
        fused[variant] = evaluate(truth, result.labels).miou or 0.0
    return ScanRow(
        name,
        len(scan),
        synthetic,
        evaluate(truth, labels).miou or 0.0,
        evaluate(truth, segment_majority(truth, segments)).miou or 0.0,
        fused,
    )


def summary(rows: list[ScanRow]) -> str:
    """Per-variant mean, mean gain, worst gain and losses over the synthetic scans (over the
    real ones when there are no synthetic scans)."""
    synth = [r for r in rows if r.synthetic]
    real = [r for r in rows if not r.synthetic]
    if not synth:
        synth, real = real, []
    lines = [
        "| variant | mean mIoU | mean gain | worst gain | scans lost |"
        + (" S3DIS fragment gain |" if real else ""),
        "|---|---|---|---|---|" + ("---|" if real else ""),
    ]
    best, best_key = None, (-1, -np.inf)
    for variant in VARIANTS:
        gains = np.array([r.fused[variant] - r.network for r in synth])
        mean = np.mean([r.fused[variant] for r in synth])
        lost = int(np.sum(gains < 0))
        line = f"| {variant} | {mean:.3f} | {gains.mean():+.3f} | {gains.min():+.3f} | {lost} |"
        if real:
            line += f" {real[0].fused[variant] - real[0].network:+.3f} |"
        lines.append(line)
        key = (int(lost == 0), float(gains.mean()))
        if key > best_key:
            best, best_key = variant, key
    lines.append("")
    lines.append(f"winner: **{best}** (best mean gain among variants that lose on no scan)")
    lines.append(f"current default: mode={DEFAULT_MODE!r}, {FusionParams().model_dump()}")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--network", choices=BACKENDS, default="randlanet")
    parser.add_argument(
        "--weights", nargs="+", default=[None], help="one or more (default: the backend's own)"
    )
    parser.add_argument(
        "--stand-in",
        action="store_true",
        help="no network: ground truth with spatially coherent noise (jointseg.synth.label_noise)",
    )
    parser.add_argument("--rooms", type=int, default=10)
    parser.add_argument("--floors", type=int, default=2)
    parser.add_argument("--points", type=int, default=300_000, help="points per room")
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    if args.stand_in:
        source = "stand-in network: ground truth with patchy label noise"

        def noisy(scan: Scan, seed: int) -> tuple[np.ndarray, np.ndarray]:
            assert scan.labels is not None, "the stand-in needs labelled scans"
            return corrupt_labels(scan.xyz, scan.labels, rng=np.random.default_rng(seed))

        labellers = {"": noisy}
    else:
        predictors = {w: load(args.network, w) for w in args.weights}
        source = ", ".join(
            f"{args.network} {w or '(default weights)'} (trained on {p.card.get('data', '?')})"
            for w, p in predictors.items()
        )

        def labeller(predictor):
            def label(scan: Scan, seed: int):
                result = predictor.predict(scan, seed=seed)
                return result.labels, result.probs

            return label

        labellers = {
            (f", {Path(w).stem}" if len(predictors) > 1 else ""): labeller(p)
            for w, p in predictors.items()
        }

    print(f"# fusion variants, {source}, {time.strftime('%F')}\n")
    rows = []
    scans = [(name, scan, True) for name, scan in held_out(args.rooms, args.floors, args.points)]
    if FRAGMENT.is_file():
        scans.append(("S3DIS fragment (real)", read_scan(FRAGMENT), False))
    for i, (name, scan, synthetic) in enumerate(scans):
        for suffix, label in labellers.items():
            t = time.perf_counter()
            rows.append(measure(name + suffix, scan, label(scan, i), i, synthetic))
            print(f"{name}{suffix}: {time.perf_counter() - t:.1f} s", file=sys.stderr)

    print("mIoU per scan (network, each fusion variant, oracle = segment majority of truth)\n")
    print("| scan | points | network | " + " | ".join(VARIANTS) + " | oracle |")
    print("|---|---|---|" + "---|" * len(VARIANTS) + "---|")
    for r in rows:
        cells = " | ".join(fmt(r.fused[v]) for v in VARIANTS)
        print(f"| {r.name} | {r.points:,} | {fmt(r.network)} | {cells} | {fmt(r.oracle)} |")
    print()
    print(summary(rows))


if __name__ == "__main__":
    main()
