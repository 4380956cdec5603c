"""Network stage benchmark: our whole-scan RandLA-Net inference vs Open3D-ML's; DGCNN's speed.

Runs, in one process on the same synthetic room and the same weights (ours converted to
Open3D-ML's layout), our `predict` and Open3D-ML's `SemanticSegmentation.run_inference`, and
prints points per second, the speed ratio and the share of points on which the two agree.
`--big N` also measures our peak memory on an N-point scan in a fresh process.

`--dgcnn [WEIGHTS]` instead times DGCNN's whole-scan inference (dgcnn.pytorch's S3DIS weights;
default $JOINTSEG_DGCNN_WEIGHTS) on the same room with the default block overlap and coverage,
and with the reference's non-overlapping blocks that predict every point, torch using
`--threads` threads (default: the cores this process may use).

    .venv/bin/python bench/network.py [--points 1000000] [--weights PATH] [--big 10000000]
    .venv/bin/python bench/network.py --dgcnn model_1.t7 [--points 1000000] [--threads 2]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import subprocess
import sys
import time

import numpy as np
import torch
from helpers.report import header

from jointseg.metrics import evaluate
from jointseg.network import DGCNNParams, load
from jointseg.network.convert import to_open3d_ml_state
from jointseg.network.registry import REGISTRY
from jointseg.synth import make_room

S3DIS_CFG = dict(
    num_neighbors=16,
    num_layers=5,
    num_points=40960,
    num_classes=13,
    ignored_label_inds=[],
    sub_sampling_ratio=[4, 4, 4, 4, 2],
    in_channels=6,
    dim_features=8,
    dim_output=[16, 64, 128, 256, 512],
    grid_size=0.04,
)


def run_open3d_ml(predictor, xyz: np.ndarray, rgb: np.ndarray) -> tuple[np.ndarray, float]:
    import open3d.ml.torch as ml3d

    # Same crop size and grid as our model's card, so both run the same scheme on the same input.
    cfg = predictor.model.config
    model = ml3d.models.RandLANet(
        **{**S3DIS_CFG, "num_points": cfg.num_points, "grid_size": cfg.grid_size}
    )
    model.load_state_dict(to_open3d_ml_state(predictor.model.state_dict()))
    pipeline = ml3d.pipelines.SemanticSegmentation(model, device="cpu")
    pts = xyz.astype(np.float32).copy()
    pts[:, 2] -= pts[:, 2].min()  # the input convention both models were given
    data = {"point": pts, "feat": rgb.astype(np.float32), "label": np.zeros(len(pts), np.int32)}
    t = time.perf_counter()
    result = pipeline.run_inference(data)
    return np.asarray(result["predict_labels"]), time.perf_counter() - t


def big_run(points: int, weights: str) -> None:
    """Child process: predict an N-point room and print peak RSS (MB) as JSON."""
    scan = make_room(7, points=points)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    t = time.perf_counter()
    load("randlanet", weights, device="cpu").predict(scan)
    seconds = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"points": points, "seconds": seconds, "peak_mb": peak, "before_mb": before}))


DGCNN_SETTINGS = {
    "stride 0.5, coverage 1": DGCNNParams(coverage=1.0),
    "default": DGCNNParams(),
    "stride 0.5, coverage 0.75": DGCNNParams(coverage=0.75),
    "stride 0.5, coverage 0.5": DGCNNParams(coverage=0.5),
    "reference blocks (stride 1, every point)": DGCNNParams(stride=1.0, coverage=None),
}


def dgcnn_speed(points: int, weights: str | None, only_default: bool = False) -> None:
    """DGCNN whole-scan inference on an N-point synthetic room, per setting."""
    scan = make_room(0, points=points)
    print(f"# DGCNN whole-scan inference, {len(scan):,} points (make_room seed 0)")
    print(f"torch threads {torch.get_num_threads()}, device cpu, {time.strftime('%F')}\n")
    print(
        "| setting | seconds | s per 100k points | samples | blocks / forward / project s "
        "| labels as the first row |"
    )
    print("|---|---|---|---|---|---|")
    first = None
    settings = {"default": DGCNNParams()} if only_default else DGCNN_SETTINGS
    for name, params in settings.items():
        predictor = load("dgcnn", weights, device="cpu", dgcnn=params)
        t = time.perf_counter()
        result = predictor.predict(scan)
        seconds = time.perf_counter() - t
        steps = " / ".join(f"{v:.1f}" for v in result.timings.values())
        print(
            f"| {name} | {seconds:.1f} | {seconds * 1e5 / len(scan):.2f} | {result.crops} | "
            f"{steps} | {1.0 if first is None else np.mean(result.labels == first):.3f} |",
            flush=True,
        )
        if first is None and not only_default:
            # the noise floor: the same setting with other random samples
            first = result.labels
            again = predictor.predict(scan, seed=1).labels
            print(f"| (same, seed 1) | | | | | {np.mean(again == first):.3f} |", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\npeak RSS {peak:.0f} MB (the scan included)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--weights", default=str(REGISTRY["randlanet"].bundled))
    parser.add_argument("--big", type=int, default=0, help="also measure memory at N points")
    parser.add_argument("--child-big", type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument(
        "--dgcnn-default-only", action="store_true", help="with --dgcnn: the default setting only"
    )
    parser.add_argument(
        "--dgcnn", nargs="?", const="", default=None, help="time DGCNN with these weights instead"
    )
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    args = parser.parse_args()
    if args.child_big:  # a child run: its stdout is one JSON line the parent reads
        big_run(args.child_big, args.weights)
        return
    header()
    if args.dgcnn is not None:
        logging.basicConfig(level=logging.WARNING)
        torch.set_num_threads(args.threads)
        dgcnn_speed(args.points, args.dgcnn or None, args.dgcnn_default_only)
        return
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    scan = make_room(0, points=args.points)
    assert scan.labels is not None and scan.rgb is not None  # synthetic rooms have both
    predictor = load("randlanet", args.weights, device="cpu")
    print(f"# network benchmark, {len(scan):,} points (make_room seed 0), weights {args.weights}")
    print(f"torch threads {torch.get_num_threads()}, device cpu, {time.strftime('%F')}")
    t = time.perf_counter()
    ours = predictor.predict(scan)
    ours_s = time.perf_counter() - t
    theirs, theirs_s = run_open3d_ml(predictor, scan.xyz, scan.rgb)
    agree = float(np.mean(ours.labels == theirs))
    print()
    print("| implementation | seconds | points/s | crops | mIoU vs ground truth |")
    print("|---|---|---|---|---|")
    m_ours = evaluate(scan.labels, ours.labels).miou or 0.0
    m_theirs = evaluate(scan.labels, theirs).miou or 0.0
    print(f"| jointseg | {ours_s:.1f} | {len(scan) / ours_s:,.0f} | {ours.crops} | {m_ours:.3f} |")
    print(
        f"| Open3D-ML run_inference | {theirs_s:.1f} | {len(scan) / theirs_s:,.0f} | - | "
        f"{m_theirs:.3f} |"
    )
    print()
    print(f"**speed-up {theirs_s / ours_s:.2f}x**, agreement {agree:.4f} of points")
    print(f"our timings: { {k: round(v, 2) for k, v in ours.timings.items()} }")
    if args.big:
        out = subprocess.run(
            [sys.executable, __file__, "--child-big", str(args.big), "--weights", args.weights],
            capture_output=True,
            text=True,
            check=True,
        )
        big = json.loads(out.stdout.strip().splitlines()[-1])
        print()
        print(
            f"{big['points']:,} points: {big['seconds']:.1f} s, peak RSS {big['peak_mb']:.0f} MB "
            f"(of which {big['before_mb']:.0f} MB held before inference: the scan itself)"
        )


if __name__ == "__main__":
    main()
