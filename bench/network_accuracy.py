"""Network accuracy on scans the training never saw: held-out synthetic rooms and floors (random
yaw, box and L shapes) and, when present, the real S3DIS fragment in ../shared/data.

Prints one row per scan (mIoU, mAcc, OA), the mean over the synthetic scans, and per-class IoU
summed over all synthetic scans.

    .venv/bin/python bench/network_accuracy.py [--weights PATH] [--rooms 10] [--floors 2]
"""

from __future__ import annotations

import argparse
import logging
import time

import numpy as np
import torch
from helpers.inputs import FRAGMENT
from helpers.report import header
from helpers.scans import held_out

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.io import read_scan
from jointseg.metrics import confusion_matrix, evaluate, per_class_iou
from jointseg.network import load
from jointseg.network.registry import REGISTRY
from jointseg.pipeline.tables import format_score as fmt


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", default=str(REGISTRY["randlanet"].bundled))
    parser.add_argument("--rooms", type=int, default=10)
    parser.add_argument("--floors", type=int, default=2)
    parser.add_argument("--points", type=int, default=500_000, help="points per room")
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    predictor = load("randlanet", args.weights)
    print(f"# network accuracy, weights {args.weights}")
    print(f"trained on: {predictor.card.get('data', '?')}")
    print(
        f"torch threads {torch.get_num_threads()}, device {predictor.device}, {time.strftime('%F')}"
    )
    print()
    print("| scan | points | mIoU | mAcc | OA | seconds |")
    print("|---|---|---|---|---|---|")
    total = np.zeros((NUM_CLASSES, NUM_CLASSES + 1), dtype=np.int64)
    mious = []
    for name, scan in held_out(args.rooms, args.floors, args.points):
        t = time.perf_counter()
        pred = predictor.predict(scan).labels
        seconds = time.perf_counter() - t
        assert scan.labels is not None  # held-out synthetic scans are labelled
        m = evaluate(scan.labels, pred)
        total += confusion_matrix(scan.labels, pred)
        mious.append(m.miou or 0.0)
        print(
            f"| {name} | {len(scan):,} | {fmt(m.miou)} | {fmt(m.macc)} | {fmt(m.oa)} | "
            f"{seconds:.1f} |"
        )
    print(f"| **mean of {len(mious)} synthetic scans** | | **{np.mean(mious):.3f}** | | | |")
    if FRAGMENT.is_file():
        scan = read_scan(FRAGMENT)
        t = time.perf_counter()
        pred = predictor.predict(scan).labels
        assert scan.labels is not None, f"{FRAGMENT} has no labels"
        m = evaluate(scan.labels, pred)
        print(
            f"| S3DIS fragment (real) | {len(scan):,} | {fmt(m.miou)} | {fmt(m.macc)} | "
            f"{fmt(m.oa)} | {time.perf_counter() - t:.1f} |"
        )
        print()
        print(
            "S3DIS fragment per-class IoU: "
            + ", ".join(f"{c} {fmt(v)}" for c, v in m.per_class_iou.items())
        )
    else:
        print(f"\n(S3DIS fragment not found at {FRAGMENT}: skipped)")
    ious = per_class_iou(total)
    print()
    print("| class | IoU over all synthetic scans |")
    print("|---|---|")
    for c, name in enumerate(CLASS_NAMES):
        print(f"| {name} | {fmt(ious[c])} |")


if __name__ == "__main__":
    main()
