"""DGCNN's published S3DIS weights on the real S3DIS fragment: the reference's reading against
the room frame, without and with block overlap.

The fragment (../shared/data/s3dis_fragment.ply) is the bottom ~1 m of an S3DIS room, so the
reference's room-normalised coordinates (divided by the scan's bounding box) are stretched
three times in z there; the room frame measures the floor and, with no ceiling in the scan,
assumes a 3 m room. Prints OA, mIoU and per-class IoU per weights file and setting, and the
seconds per 100 000 points.

    OMP_NUM_THREADS=1 .venv/bin/python bench/dgcnn_fragment.py [--models 1 2 3 4 5 6]
        [--weights-dir ../shared/models/dgcnn_s3dis] [--scan FILE]
"""

from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import torch
from helpers.inputs import FRAGMENT, MODELS
from helpers.report import header

from jointseg.classes import CLASS_NAMES
from jointseg.io import read_scan
from jointseg.metrics import evaluate
from jointseg.network import DGCNNParams, load
from jointseg.pipeline.tables import format_score as fmt

WEIGHTS_DIR = MODELS / "dgcnn_s3dis"
SETTINGS = {
    "reference (scan box, stride 1)": DGCNNParams(frame="scan", stride=1.0),
    "scan box, stride 0.5": DGCNNParams(frame="scan"),
    "room frame, stride 1": DGCNNParams(stride=1.0),
    "room frame, stride 0.5, coverage 1": DGCNNParams(coverage=1.0),
    "room frame, stride 0.5, coverage 0.75": DGCNNParams(coverage=0.75),
    "room frame, stride 0.5, coverage 0.5": DGCNNParams(coverage=0.5),
    "default": DGCNNParams(),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=int, nargs="+", default=[1, 2, 3, 4, 5, 6])
    parser.add_argument("--weights-dir", type=Path, default=WEIGHTS_DIR)
    parser.add_argument("--scan", type=Path, default=FRAGMENT)
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    scan = read_scan(args.scan)
    if scan.labels is None:
        raise SystemExit(f"{args.scan} has no ground truth")
    present = [c for c in range(len(CLASS_NAMES)) if (scan.labels == c).any()]
    print(f"# DGCNN on {args.scan.name} ({len(scan):,} points), {time.strftime('%F')}")
    print(f"torch threads {torch.get_num_threads()}, cpu\n")
    columns = ["weights", "setting", "OA", "mIoU", *(CLASS_NAMES[c] for c in present), "s/100k"]
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for model in args.models:
        weights = args.weights_dir / f"model_{model}.t7"
        for name, params in SETTINGS.items():
            predictor = load("dgcnn", weights, device="cpu", dgcnn=params)
            t = time.perf_counter()
            result = predictor.predict(scan)
            seconds = time.perf_counter() - t
            m = evaluate(scan.labels, result.labels)
            ious = [fmt(m.per_class_iou[CLASS_NAMES[c]]) for c in present]
            row = [f"model_{model}", name, fmt(m.oa), fmt(m.miou), *ious]
            row.append(f"{seconds * 1e5 / len(scan):.1f}")
            print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
