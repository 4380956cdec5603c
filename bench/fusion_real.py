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
import functools
import hashlib
import logging
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from network_accuracy import held_out

from jointseg.classes import CLASS_NAMES
from jointseg.fusion import fuse
from jointseg.fusion.variants import DEFAULT_VARIANT, VARIANTS
from jointseg.geometry import GeometryParams, segment
from jointseg.io import read_scan
from jointseg.metrics import (
    confusion_matrix,
    evaluate,
    per_class_iou,
    segment_majority,
    segment_purity,
)
from jointseg.network.train_data import stable_order
from jointseg.pipeline.tables import format_score as fmt
from jointseg.scan import Scan

SHARED = Path(__file__).resolve().parents[2] / "shared"
AREA6 = SHARED / "data" / "s3dis_area6"
SCANNET = SHARED / "data" / "scannet"
#: ScanNet rooms judged (every re-scan of a room on one side): the three the bundled RandLA-Net
#: never trained on (scene0002 and scene0007 excluded, scene0005 its validation room).
SCANNET_JUDGES = ("scene0002", "scene0005", "scene0007")
#: Folder (or file stem) -> dataset name in the tables.
DATASET_NAMES = {"s3dis_area6": "S3DIS", "scannet": "ScanNet", "s3dis_fragment": "S3DIS fragment"}
CACHE = Path(__file__).parent / "_cache"
LOST = -0.005  # a room "lost" below network - 0.5 mIoU points

#: Geometry settings compared (name -> GeometryParams overrides).
GEOMETRY: dict[str, dict] = {
    "default": {},
    "colour0.6": {"colour_scale": 0.6},
    "colour0.6-min10": {"colour_scale": 0.6, "min_region_points": 10},
    "voxel1.5": {"voxel_factor": 1.5},
    "colour0.4": {"colour_scale": 0.4},
    "colour0.4-min10": {"colour_scale": 0.4, "min_region_points": 10},
    "colour0.3-min10": {"colour_scale": 0.3, "min_region_points": 10},
}


@dataclass
class Item:
    """One labelled scan and where it belongs."""

    name: str
    scan: Scan
    key: str  # content hash for the cache
    split: str  # "judge", "tune" or "synthetic"
    dataset: str = "synthetic"
    room: str = ""  # scans of one room share it (ScanNet re-scans)


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
    cm_net: np.ndarray | None = None
    cm_fused: dict[str, np.ndarray] = field(default_factory=dict)


def content_key(*parts: object) -> str:
    """A short hash of the parts (arrays by their bytes)."""
    h = hashlib.sha1()
    for p in parts:
        h.update(p.tobytes() if isinstance(p, np.ndarray) else repr(p).encode())
    return h.hexdigest()[:16]


def cached(path: Path, compute) -> dict[str, np.ndarray]:
    """Arrays from ``path`` (npz) if there, else ``compute()`` saved there."""
    if path.is_file():
        with np.load(path) as data:
            return {k: data[k] for k in data.files}
    out = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **out)
    tmp.replace(path)
    return out


def dataset_of(path: Path) -> str:
    """The dataset a scan belongs to, by its folder (or, for a lone file, its stem)."""
    key = path.parent.name if path.parent.name in DATASET_NAMES else path.stem
    return DATASET_NAMES.get(key, path.parent.name)


def room_of(stem: str) -> str:
    """The room a scan shows: ScanNet's ``sceneNNNN_MM`` re-scans share ``sceneNNNN``."""
    return re.sub(r"^(scene\d{4})_\d{2}$", r"\1", stem)


def judging_rooms(dataset: str, rooms: list[str], judge: int) -> set[str]:
    """Rooms judged: ScanNet's fixed three (see SCANNET_JUDGES), else the first ``judge`` rooms
    of the dataset in name-hash order."""
    if dataset == "ScanNet":
        return set(SCANNET_JUDGES)
    return set(stable_order(rooms)[:judge])


def load_items(paths: list[str], judge: int, synth: tuple[int, int, int]) -> list[Item]:
    """Real labelled scans (split by room, per dataset) and held-out synthetic ones."""
    files: list[Path] = []
    for p in paths:
        if p == "none":
            continue
        path = Path(p)
        files += sorted(path.glob("*.ply")) if path.is_dir() else [path]
    rooms_by_dataset: dict[str, list[str]] = {}
    for f in files:
        rooms_by_dataset.setdefault(dataset_of(f), []).append(room_of(f.stem))
    judges = {d: judging_rooms(d, sorted(set(r)), judge) for d, r in rooms_by_dataset.items()}
    items = []
    for f in files:
        scan = read_scan(f)
        if scan.labels is None:
            raise SystemExit(f"{f}: no label field")
        key = content_key(scan.xyz, scan.labels)
        dataset, room = dataset_of(f), room_of(f.stem)
        split = "judge" if room in judges[dataset] else "tune"
        items.append(Item(f.stem, scan, key, split, dataset, room))
    rooms, floors, points = synth
    for name, scan in held_out(rooms, floors, points):
        items.append(Item(name, scan, content_key(name, points), "synthetic", "synthetic", name))
    return items


def network_output(spec: str, item: Item, predictors: dict) -> tuple[np.ndarray, np.ndarray]:
    """Labels and probabilities of network ``spec`` ("backend[:weights]") on a scan, cached."""

    def compute() -> dict[str, np.ndarray]:
        from jointseg.network import load

        if spec not in predictors:
            backend, _, weights = spec.partition(":")
            predictors[spec] = load(backend, weights or None)
        result = predictors[spec].predict(item.scan, seed=0)
        return {"labels": result.labels.astype(np.int8), "probs": result.probs.astype(np.float16)}

    key = content_key(spec, weights_fingerprint(spec), INFERENCE_VERSION)
    out = cached(CACHE / "net" / f"{item.key}-{key}.npz", compute)
    return out["labels"].astype(np.int64), out["probs"].astype(np.float32)


#: Part of every cached network output's key: bump it when whole-scan inference changes what it
#: computes (2: RandLA-Net's linear possibility weight; 3: classes a scan does not hold taken
#: out, RandLANetParams.absent_share), so no stale labels are reused.
INFERENCE_VERSION = 3


@functools.cache
def weights_fingerprint(spec: str) -> str:
    """Size and modification time of the weights file ``spec`` resolves to: a spec without a
    path ("randlanet") names whatever weights are bundled now, so the key must follow them."""
    from jointseg.network.registry import resolve_weights

    backend, _, weights = spec.partition(":")
    path = resolve_weights(backend, weights or None)
    if path is None or not path.is_file():
        return "none"
    stat = path.stat()
    return f"{stat.st_size}-{stat.st_mtime_ns}"


def geometry_output(name: str, item: Item) -> dict[str, np.ndarray]:
    """Segments and main-plane ids of geometry setting ``name`` on a scan, cached."""
    params = GeometryParams(**GEOMETRY[name])

    def compute() -> dict[str, np.ndarray]:
        result = segment(item.scan, params, seed=0)
        return {"segments": result.segments, "plane_id": result.plane_id}

    return cached(
        CACHE / "geo" / f"{item.key}-{content_key(params.model_dump_json())}.npz", compute
    )


def network_name(spec: str) -> str:
    """A network spec as the tables name it: its weights file, or the bare backend."""
    return spec.rpartition("/")[2] or spec


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
            item.scan.xyz, segs, labels, probs, VARIANTS[v], main_plane=g["plane_id"] >= 0
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
    cm_n = sum(r.cm_net for r in rows)
    cm_f = sum(r.cm_fused[variant] for r in rows)
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
