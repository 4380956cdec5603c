"""Network labels alone, per dataset, for several weights side by side.

Scores whole-scan predictions (``jointseg.network.load(...).predict``: the labels
``jointseg segment`` writes as its network field) on:
- real S3DIS Area_6 rooms (../shared/data/s3dis_area6; ``--area6-judge`` names the rooms a
  training run never saw, the others are reported as "seen by some weights");
- real ScanNet scans (../shared/data/scannet), judging rooms only (``--scannet-judge``, room
  prefixes such as scene0002 so re-scans of one room stay together), tuning rooms reported
  apart;
- the real S3DIS fragment (a bottom slice of a room);
- held-out synthetic rooms and a floor (seeds 5000+/6000+, never used by training).

Prints one table per dataset (mean and worst mIoU per weights) and a summary table.

    .venv/bin/python bench/network_datasets.py --weights bundled \\
        --weights ../shared/models/randlanet_area6_gpu/randlanet_area6_gpu.pt
"""

from __future__ import annotations

import argparse
import logging
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from helpers.inputs import AREA6, FRAGMENT, SCANNET
from helpers.report import header

from jointseg.io import read_scan
from jointseg.metrics import evaluate
from jointseg.network import load
from jointseg.network.registry import REGISTRY
from jointseg.scan import Scan

#: Rooms the handed-over GPU checkpoint's stage 1 never trained on; stage 2 saw all but office_4.
AREA6_JUDGE = ("area6_office_4",)
#: ScanNet rooms kept out of training and checkpoint selection (every re-scan of each).
SCANNET_JUDGE = ("scene0002", "scene0007")
#: ScanNet room used to pick the best checkpoint (validation); not judged.
SCANNET_VAL = ("scene0005",)


def without_colour(scan: Scan) -> Scan:
    """The scan as a sensor without colour delivers it."""
    return Scan(xyz=scan.xyz, rgb=None, labels=scan.labels)


def _colourless(load: Callable[[], Scan]) -> Scan:
    return without_colour(load())


def _files(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.ply")) if folder.is_dir() else []


def datasets(args: argparse.Namespace) -> dict[str, list[tuple[str, Callable[[], Scan]]]]:
    """Dataset name -> (scan name, loader) pairs; loaders so scans are read once, lazily."""
    out: dict[str, list[tuple[str, Callable[[], Scan]]]] = {}
    area6 = _files(AREA6)
    judge6 = [p for p in area6 if p.stem in args.area6_judge]
    seen6 = [p for p in area6 if p.stem not in args.area6_judge]
    if judge6:
        out["Area_6 judging rooms"] = [(p.stem, partial(read_scan, p)) for p in judge6]
    if seen6 and args.area6_all:
        out["Area_6 other rooms (seen in training)"] = [
            (p.stem, partial(read_scan, p)) for p in seen6
        ]
    scannet = _files(SCANNET)
    judge = [p for p in scannet if p.stem.split("_")[0] in args.scannet_judge]
    val = [p for p in scannet if p.stem.split("_")[0] in SCANNET_VAL]
    if judge:
        out["ScanNet judging rooms"] = [(p.stem, partial(read_scan, p)) for p in judge]
    if val:
        out["ScanNet validation room"] = [(p.stem, partial(read_scan, p)) for p in val]
    if FRAGMENT.is_file():
        out["S3DIS fragment"] = [(FRAGMENT.stem, partial(read_scan, FRAGMENT))]
    if args.synth_rooms or args.synth_floors:
        from jointseg.synth import make_floor, make_room

        synth: list[tuple[str, Callable[[], Scan]]] = []
        for i in range(args.synth_rooms):
            shape: Literal["box", "L"] = "L" if i % 2 else "box"
            room = partial(make_room, 5000 + i, points=args.synth_points, shape=shape)
            synth.append((f"room {5000 + i} ({shape})", room))
        for i in range(args.synth_floors):
            floor = partial(make_floor, 6000 + i, points=3 * args.synth_points)
            synth.append((f"floor {6000 + i}", floor))
        out["synthetic (held out)"] = synth
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--weights",
        action="append",
        default=[],
        help="'bundled', a RandLA-Net checkpoint or dgcnn:PATH; repeat",
    )
    parser.add_argument(
        "--absent-share",
        type=float,
        default=None,
        help="RandLA-Net's absent-class share (default: the library's; 0 turns it off)",
    )
    parser.add_argument("--area6-judge", nargs="*", default=list(AREA6_JUDGE))
    parser.add_argument("--area6-all", action="store_true", help="also score the seen rooms")
    parser.add_argument("--scannet-judge", nargs="*", default=list(SCANNET_JUDGE))
    parser.add_argument("--synth-rooms", type=int, default=4)
    parser.add_argument("--synth-floors", type=int, default=1)
    parser.add_argument("--synth-points", type=int, default=300_000)
    parser.add_argument(
        "--no-colour", action="store_true", help="score every scan without its colour"
    )
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    weights = args.weights or ["bundled"]
    backends = ["dgcnn" if w.startswith("dgcnn:") else "randlanet" for w in weights]
    paths = [
        str(REGISTRY["randlanet"].bundled) if w == "bundled" else w.removeprefix("dgcnn:")
        for w in weights
    ]
    names = [w if w == "bundled" else Path(w).stem for w in weights]
    options = {} if args.absent_share is None else {"absent_share": args.absent_share}
    predictors = [
        load(b, p, params=options if b == "randlanet" else None)
        for b, p in zip(backends, paths, strict=True)
    ]
    print(
        f"# network labels alone per dataset, {time.strftime('%F')}, "
        f"torch {torch.__version__}, {torch.get_num_threads()} threads"
    )
    for name, path in zip(names, paths, strict=True):
        print(f"# {name}: {path}")
    if args.absent_share is not None:
        print(f"# RandLA-Net absent_share {args.absent_share}")
    summary: list[tuple[str, list[tuple[float, float]]]] = []
    for dataset, scans in datasets(args).items():
        if args.no_colour:
            scans = [(n, partial(_colourless, load)) for n, load in scans]
        print(f"\n## {dataset}\n")
        print("| scan | points | " + " | ".join(names) + " |")
        print("|---|---|" + "---|" * len(names))
        scores: list[list[float]] = [[] for _ in names]
        for scan_name, loader in scans:
            scan = loader()
            row = []
            for k, predictor in enumerate(predictors):
                assert scan.labels is not None, f"{scan_name} has no labels"
                miou = evaluate(scan.labels, predictor.predict(scan).labels).miou or 0.0
                scores[k].append(miou)
                row.append(f"{miou:.3f}")
            print(f"| {scan_name} | {len(scan):,} | " + " | ".join(row) + " |")
        stats = [(float(np.mean(s)), float(np.min(s))) for s in scores]
        print(
            "| **mean (worst)** | | "
            + " | ".join(f"**{m:.3f}** ({w:.3f})" for m, w in stats)
            + " |"
        )
        summary.append((dataset, stats))
    print("\n## summary: mean mIoU (worst scan)\n")
    print("| dataset | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for dataset, stats in summary:
        print(f"| {dataset} | " + " | ".join(f"{m:.3f} ({w:.3f})" for m, w in stats) + " |")


if __name__ == "__main__":
    main()
