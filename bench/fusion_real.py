"""Fusion on real labelled scans: networks x geometry settings x fusion variants, tune/judge split.

For every labelled scan (folders of them, default the 25 real S3DIS Area_6 rooms in
../shared/data/s3dis_area6 and the 14 ScanNet scans in ../shared/data/scannet; optionally the
real fragment and held-out synthetic seeds), every network labels it once and every geometry
setting segments it once (both cached on disk under bench/_cache, keyed by the file's content
and the settings); then every fusion variant fuses each pair. Each scan belongs to a dataset
(its folder) and a room (ScanNet's re-scans share one). Per dataset, rooms are split into
judging rooms (the first --judge in name-hash order; ScanNet: scene0002, 0005 and 0007, which
the bundled network never trained on) and tuning rooms: choose on the tuning rooms, report the
judging ones. The last table gives the default variant's gain per dataset x network x split.

Prints, per network and geometry setting:
- Table 2 (as the paper): per room network / fused mIoU of each variant / oracle, purity and
  segment count;
- a summary per variant and split: mean and worst gain (mIoU points), rooms lost (gain < -0.5);
- Table 1 (as the paper): per-class IoU of the network and the default variant over the judging
  rooms, and the gain per class.
and writes every row as CSV (--csv).

    .venv/bin/python bench/fusion_real.py --network dgcnn:../shared/models/dgcnn_s3dis/model_6.t7
    .venv/bin/python bench/fusion_real.py --scans ../shared/data/s3dis_fragment.ply \\
        --network dgcnn:.../model_1.t7 ... --network randlanet --judge 1
    .venv/bin/python bench/fusion_real.py --scans none --synth-rooms 6 --synth-floors 2 \\
        --network randlanet
"""

from __future__ import annotations

import argparse
import csv
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from helpers.inputs import AREA6, SCANNET
from helpers.report import header
from helpers.scans import (
    GEOMETRY,
    SCANNET_JUDGES,
    Item,
    geometry_output,
    load_items,
    network_name,
    network_output,
    structure_hint,
)

from jointseg.classes import CLASS_NAMES
from jointseg.fusion import fuse
from jointseg.fusion.variants import DEFAULT_VARIANT, VARIANTS
from jointseg.metrics import (
    confusion_matrix,
    evaluate,
    per_class_iou,
    segment_majority,
    segment_purity,
)
from jointseg.pipeline.tables import format_score as fmt

LOST = -0.005  # a room "lost" below network - 0.5 mIoU points


@dataclass
class Row:
    """One scan x network x geometry: scores of the network, the oracle and each variant."""

    scan: str
    split: str
    dataset: str
    network: str
    geometry: str
    points: int
    segments: int
    purity: float
    net_miou: float
    oracle: float
    fused: dict[str, float] = field(default_factory=dict)
    cm_net: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    cm_fused: dict[str, np.ndarray] = field(default_factory=dict)


def measure(item: Item, spec: str, geo: str, variants: list[str], predictors: dict) -> Row:
    labels, probs = network_output(spec, item, predictors)
    g = geometry_output(geo, item)
    gt = item.scan.labels
    assert gt is not None
    segs = g["segments"]
    row = Row(
        item.name,
        item.split,
        item.dataset,
        network_name(spec),
        geo,
        len(item.scan),
        int(len(np.unique(segs))),
        segment_purity(gt, segs),
        evaluate(gt, labels).miou or 0.0,
        evaluate(gt, segment_majority(gt, segs)).miou or 0.0,
        cm_net=confusion_matrix(gt, labels),
    )
    for v in variants:
        result = fuse(
            item.scan.xyz,
            segs,
            labels,
            probs,
            VARIANTS[v],
            main_plane=g["plane_id"] >= 0,
            structure=structure_hint(g),
        )
        row.fused[v] = evaluate(gt, result.labels).miou or 0.0
        row.cm_fused[v] = confusion_matrix(gt, result.labels)
    return row


def table2(rows: list[Row], variants: list[str]) -> str:
    head = "| scan | dataset | split | points | segments | purity | network | "
    lines = [head + " | ".join(variants) + " | oracle |", "|---" * (8 + len(variants)) + "|"]
    for r in rows:
        cells = " | ".join(fmt(r.fused[v]) for v in variants)
        lines.append(
            f"| {r.scan} | {r.dataset} | {r.split} | {r.points:,} | {r.segments} | "
            f"{r.purity:.3f} | "
            f"{fmt(r.net_miou)} | {cells} | {fmt(r.oracle)} |"
        )
    return "\n".join(lines)


def summary(rows: list[Row], variants: list[str]) -> str:
    splits = [s for s in ("tune", "judge", "synthetic") if any(r.split == s for r in rows)]
    head = "| variant | " + " | ".join(f"{s}: mean / worst gain, lost" for s in splits) + " |"
    lines = [head, "|---" * (1 + len(splits)) + "|"]
    for v in variants:
        cells = []
        for s in splits:
            gains = np.array([r.fused[v] - r.net_miou for r in rows if r.split == s])
            cells.append(
                f"{100 * gains.mean():+.1f} / {100 * gains.min():+.1f}, {int((gains < LOST).sum())}"
            )
        lines.append(f"| {v} | " + " | ".join(cells) + " |")
    for s in splits:
        sel = [r for r in rows if r.split == s]
        net, oracle = np.mean([r.net_miou for r in sel]), np.mean([r.oracle for r in sel])
        lines.append(
            f"\n{s}: {len(sel)} scans, network mIoU {net:.3f}, purity "
            f"{np.mean([r.purity for r in sel]):.3f}, segments "
            f"{np.mean([r.segments for r in sel]):.0f}, oracle {oracle:.3f}"
        )
    return "\n".join(lines)


def groups(rows: list[Row], variant: str) -> str:
    """Gain of ``variant`` per dataset x network x split: the issue's acceptance table."""
    head = (
        "| dataset | network | split | scans | network mIoU | purity | mean gain | worst | lost |"
    )
    lines = [head, "|---" * 9 + "|"]
    keys = sorted({(r.dataset, r.network, r.split) for r in rows})
    for dataset, network, split in keys:
        sel = [r for r in rows if (r.dataset, r.network, r.split) == (dataset, network, split)]
        g = 100 * np.array([r.fused[variant] - r.net_miou for r in sel])
        lines.append(
            f"| {dataset} | {network} | {split} | {len(sel)} | "
            f"{np.mean([r.net_miou for r in sel]):.3f} | {np.mean([r.purity for r in sel]):.3f} | "
            f"{g.mean():+.1f} | {g.min():+.1f} | {int((g < 100 * LOST).sum())} |"
        )
    return "\n".join(lines)


def table1(rows: list[Row], variant: str) -> str:
    """Per-class IoU over the pooled confusion of the rows: network, fused, gain."""
    cm_n = np.sum([r.cm_net for r in rows], axis=0)
    cm_f = np.sum([r.cm_fused[variant] for r in rows], axis=0)
    iou_n, iou_f = per_class_iou(cm_n), per_class_iou(cm_f)
    lines = ["| | " + " | ".join(CLASS_NAMES) + " |", "|---" * (1 + len(CLASS_NAMES)) + "|"]
    lines.append("| network | " + " | ".join(fmt(x) for x in iou_n) + " |")
    lines.append(f"| {variant} | " + " | ".join(fmt(x) for x in iou_f) + " |")
    gains = [
        "/" if a is None or b is None else f"{100 * (b - a):+.1f}"
        for a, b in zip(iou_n, iou_f, strict=True)
    ]
    lines.append("| gain (points) | " + " | ".join(gains) + " |")
    return "\n".join(lines)


def write_csv(path: Path, rows: list[Row], variants: list[str]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(
            [
                "scan",
                "dataset",
                "split",
                "network",
                "geometry",
                "points",
                "segments",
                "purity",
                "network_miou",
                "oracle_miou",
                "variant",
                "fused_miou",
                "gain",
            ]
        )
        for r in rows:
            for v in variants:
                w.writerow(
                    [
                        r.scan,
                        r.dataset,
                        r.split,
                        r.network,
                        r.geometry,
                        r.points,
                        r.segments,
                        f"{r.purity:.4f}",
                        f"{r.net_miou:.4f}",
                        f"{r.oracle:.4f}",
                        v,
                        f"{r.fused[v]:.4f}",
                        f"{r.fused[v] - r.net_miou:+.4f}",
                    ]
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--scans", nargs="+", default=[str(AREA6), str(SCANNET)], help="files/folders, or none"
    )
    parser.add_argument(
        "--network", action="append", help="backend[:weights]; repeat (default randlanet)"
    )
    parser.add_argument("--geometry", nargs="+", default=["default"], choices=list(GEOMETRY))
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument(
        "--judge",
        type=int,
        default=10,
        help="judging rooms per dataset (name-hash order; "
        "ScanNet: always " + ", ".join(SCANNET_JUDGES) + ")",
    )
    parser.add_argument("--synth-rooms", type=int, default=0)
    parser.add_argument("--synth-floors", type=int, default=0)
    parser.add_argument("--synth-points", type=int, default=300_000)
    parser.add_argument("--csv", type=Path)
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    items = load_items(
        args.scans, args.judge, (args.synth_rooms, args.synth_floors, args.synth_points)
    )
    predictors: dict = {}
    rows: list[Row] = []
    variant = DEFAULT_VARIANT if DEFAULT_VARIANT in args.variants else args.variants[0]
    for spec in args.network or ["randlanet"]:
        for geo in args.geometry:
            block = []
            for item in items:
                t = time.perf_counter()
                block.append(measure(item, spec, geo, args.variants, predictors))
                print(f"{item.name} {spec} {geo}: {time.perf_counter() - t:.1f} s", file=sys.stderr)
            rows += block
            print(f"\n## {spec}, geometry {geo} ({time.strftime('%F')})\n")
            print(table2(block, args.variants))
            print()
            print(summary(block, args.variants))
            judged = [r for r in block if r.split == "judge"] or block
            print(f"\nper-class IoU over {len(judged)} {judged[0].split} scans, {variant}:\n")
            print(table1(judged, variant))
    print(f"\n## gain of {variant} per dataset x network ({time.strftime('%F')})\n")
    print(groups(rows, variant))
    if args.csv:
        write_csv(args.csv, rows, args.variants)


if __name__ == "__main__":
    main()
