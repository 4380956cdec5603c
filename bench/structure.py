"""Structure from the scan's own geometry (issue 43): what the reading adds to the fused labels.

For every judging scan, levelled by the frame stage with the up axis forced to +z
(bench/helpers/scans.py's split: S3DIS Area_6's first --judge rooms in name-hash order,
ScanNet's scene0002, 0005 and 0007; and the same Area_6 rooms thinned to one point per 3.3 cm,
the sparser segments of another building) and every network (the bundled RandLA-Net, the
colour-free one, DGCNN model_6 where its weights are on this machine):

- pooled per-class IoU and mIoU of the network (the colour-free one on the scans without their
  colour), of the vote before (the vote model of
  ``--before-ref``, which knew no structure reading) and after (the shipped model with the
  reading's offers);
- every scan's gain of the vote over the network, the worst, and how many scans lose more
  than half a point (the issue's bar);
- on the ScanNet judging scans, the ceiling height and floor area of the rooms built from the
  labels (jointseg.objects.find_layout), before and after, against the ground truth's: the
  height is the median ceiling minus the median floor (scans with a labelled ceiling); the
  floor area is that of the rooms built from the true labels (the floor enclosed by the true
  walls, as a BIM user measures it), with the seen floor's closed footprint beside it (it
  leaves out the floor hidden under furniture along the walls);
- with ``--speed``, the structure step's seconds on the 1 M-point synthetic room (median of 3
  whole geometry runs, the step's own timer).

Network and geometry outputs are cached under bench/_cache (bench/helpers/scans.py).

    .venv/bin/python bench/structure.py [--networks bundled,nocolour,dgcnn] [--splits judge,tune]
        [--before-ref 4dc3e5d] [--speed] [--flip-threshold 0.5 --metric-iou 0.8]
"""

from __future__ import annotations

import argparse
import logging
import statistics
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from helpers.inputs import AREA6, M6, MODELS, SCANNET
from helpers.report import LOSS_BAR, header, metric_iou_value
from helpers.scans import (
    Item,
    colourless,
    content_key,
    geometry_output,
    load_items,
    network_output,
    structure_hint,
    thinned,
)
from scipy import ndimage

from jointseg.classes import CLASS_INDEX, CLASS_NAMES, NUM_CLASSES
from jointseg.frame.decide import decide_frame
from jointseg.frame.params import FrameParams
from jointseg.fusion import FusionParams, fuse
from jointseg.fusion.evidence import point_probs
from jointseg.fusion.learned import learned_labels
from jointseg.fusion.tree_runtime import TreeEnsemble
from jointseg.metrics import confusion_matrix
from jointseg.objects.layout import find_layout
from jointseg.scan import Scan
from jointseg.spacing import estimate_spacing

ROOT = Path(__file__).resolve().parents[1]
NETWORKS = {
    "bundled": "randlanet",
    "nocolour": f"randlanet:{ROOT / 'jointseg/network/weights/randlanet_indoor_nocolour.pt'}",
    "dgcnn": M6,
}
FLOOR, CEILING = CLASS_INDEX["floor"], CLASS_INDEX["ceiling"]


@dataclass
class Pool:
    """Confusion matrices summed over scans, and each scan's mIoU."""

    cm: dict[str, np.ndarray] = field(default_factory=dict)
    scans: list[tuple[str, dict[str, float]]] = field(default_factory=list)

    def add(self, name: str, gt: np.ndarray, labels: dict[str, np.ndarray]) -> None:
        scores = {}
        for what, pred in labels.items():
            cm = confusion_matrix(gt[gt >= 0], pred[gt >= 0])
            self.cm[what] = self.cm.get(what, 0) + cm
            scores[what] = miou(cm)
        self.scans.append((name, scores))


def ious(cm: np.ndarray) -> np.ndarray:
    """Per-class IoU, NaN for a class neither in the truth nor predicted (``cm``'s last column
    counts invalid predictions)."""
    tp = np.diag(cm).astype(np.float64)
    union = cm[:, :NUM_CLASSES].sum(0) + cm.sum(1) - tp
    return np.where(union > 0, tp / np.maximum(union, 1), np.nan)


def miou(cm: np.ndarray) -> float:
    """Mean IoU over the classes present in the truth."""
    present = cm.sum(1) > 0
    return float(np.nanmean(np.where(present, ious(cm), np.nan)))


def levelled(item: Item) -> Item:
    """The scan as the pipeline's frame stage hands it on, with the up axis forced to +z (the
    frame forced right): levelled where tilted (ScanNet's scene0002_00 leans 7.6 degrees), as
    every stage sees it in a real run. Unchanged when already level."""
    frame = decide_frame(item.scan, FrameParams(up="+z"))
    if frame.identity:
        return item
    s = item.scan
    scan = Scan(xyz=frame.to_work(s.xyz).astype(np.float32), rgb=s.rgb, labels=s.labels)
    return Item(item.name, scan, content_key(item.key, "levelled"), item.split, item.dataset,
                item.room)  # fmt: skip


def before_model(ref: str) -> TreeEnsemble:
    """The vote model the library shipped at git ``ref``."""
    body = subprocess.run(["git", "show", f"{ref}:jointseg/fusion/vote_model.json"], cwd=ROOT,
                          capture_output=True, text=True, check=True).stdout  # fmt: skip
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "vote_model.json"
        path.write_text(body)
        return TreeEnsemble.from_json(path)


def votes(
    item: Item,
    spec: str,
    predictors: dict,
    before: TreeEnsemble,
    after: FusionParams | None = None,
) -> dict[str, np.ndarray]:
    """Network labels and the vote's before and after on one scan; "after" with ``after``
    (default: the library's parameters), "before" always at the library's default threshold."""
    labels, probs = network_output(spec, item, predictors)
    g = geometry_output("default", item)
    seg = g["segments"].astype(np.int64)
    params = FusionParams()
    after = after or params
    old, _ = learned_labels(
        item.scan.xyz, seg, int(seg.max()) + 1, labels, point_probs(labels, probs),
        threshold=params.flip_threshold, min_support=params.min_support,
        main_plane=g["plane_id"] >= 0, model=before,
    )  # fmt: skip
    new = fuse(item.scan.xyz, seg, labels, probs, after, main_plane=g["plane_id"] >= 0,
               structure=structure_hint(g), has_colour=item.scan.rgb is not None)  # fmt: skip
    return {"network": labels, "before": old, "after": new.labels.astype(np.int64)}


def true_rooms(scan: Scan) -> tuple[float | None, float]:
    """Ground-truth ceiling height (median ceiling minus median floor; None without 200 ceiling
    points) and floor area (the floor points' 10 cm cells, holes closed)."""
    gt, z = scan.labels, scan.xyz[:, 2]
    assert gt is not None
    floor, ceiling = gt == FLOOR, gt == CEILING
    height = float(np.median(z[ceiling]) - np.median(z[floor])) if ceiling.sum() >= 200 else None
    cells = np.floor(scan.xyz[floor, :2] / 0.1).astype(np.int64)
    cells -= cells.min(axis=0)
    grid = np.zeros(cells.max(axis=0) + 1, bool)
    grid[cells[:, 0], cells[:, 1]] = True
    closed = ndimage.binary_fill_holes(ndimage.binary_closing(grid, iterations=3))
    return height, float(closed.sum()) * 0.01


def layout_rooms(item: Item, labels: np.ndarray, structure: np.ndarray | None) -> tuple:
    """Ceiling height (median over rooms) and total floor area of the rooms built from
    ``labels`` (with the structure reading's levels where given)."""
    report = find_layout(item.scan.xyz, labels, None, estimate_spacing(item.scan.xyz),
                         structure=structure).report  # fmt: skip
    heights = [r.ceiling_height for r in report.rooms if r.ceiling_height is not None]
    area = sum(r.floor_area for r in report.rooms)
    return (statistics.median(heights) if heights else None), area


def print_pool(title: str, pool: Pool) -> None:
    print(f"\n### {title}: pooled IoU over {len(pool.scans)} scans\n")
    print("| labels | mIoU | " + " | ".join(CLASS_NAMES) + " |")
    print("|---" * (2 + NUM_CLASSES) + "|")
    for what, cm in pool.cm.items():
        cells = " | ".join("-" if np.isnan(v) else f"{v:.3f}" for v in ious(cm))
        print(f"| {what} | **{miou(cm):.3f}** | {cells} |")
    gains = [(100 * (s["after"] - s["network"]), 100 * (s["before"] - s["network"]), n)
             for n, s in pool.scans]  # fmt: skip
    worst = min(gains)
    losing = sum(g[0] < -LOSS_BAR for g in gains)
    after, before = np.mean([g[0] for g in gains]), np.mean([g[1] for g in gains])
    print(f"\nvote against the network, points: after mean {after:+.2f}, worst {worst[0]:+.2f} "
          f"({worst[2]}), {losing} losing over {LOSS_BAR}; before mean {before:+.2f}, "
          f"worst {min(g[1] for g in gains):+.2f}")  # fmt: skip
    for name, s in pool.scans:
        print(f"  {name:24s} network {s['network']:.3f} before {s['before']:.3f} "
              f"after {s['after']:.3f} ({100 * (s['after'] - s['network']):+.2f})")  # fmt: skip


def speed() -> None:
    """The structure step's seconds on the 1 M-point synthetic room (median of 3)."""
    from jointseg.geometry import segment
    from jointseg.synth import make_room

    room = make_room(1501, points=1_000_000)
    runs = [segment(room, seed=0).timings for _ in range(3)]
    step = statistics.median(t["structure"] for t in runs)
    whole = statistics.median(sum(t.values()) for t in runs)
    print(f"\nstructure step on 1 M points: {step:.3f} s (median of 3), {100 * step / whole:.1f} % "
          f"of the geometry stage ({whole:.2f} s); bar 0.5 s")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--networks", default="bundled,nocolour,dgcnn")
    parser.add_argument("--splits", default="judge")
    parser.add_argument("--judge", type=int, default=10)
    parser.add_argument("--before-ref", default="4dc3e5d")
    parser.add_argument("--speed", action="store_true")
    parser.add_argument("--flip-threshold", type=float, help="the vote's (default: library's)")
    parser.add_argument(
        "--metric-iou",
        type=metric_iou_value,
        help="the vote's: auto, or one IoU for every class (default: library's)",
    )
    args = parser.parse_args()
    chosen = {"flip_threshold": args.flip_threshold, "metric_iou": args.metric_iou}
    after = FusionParams(**{k: v for k, v in chosen.items() if v is not None})
    header()
    logging.basicConfig(level=logging.WARNING)
    print(f"`{Path(sys.argv[0]).name} {' '.join(sys.argv[1:])}`")
    before = before_model(args.before_ref)
    splits = args.splits.split(",")
    items = [i for i in load_items([str(AREA6), str(SCANNET)], args.judge, (0, 0, 0))
             if i.split in splits]  # fmt: skip
    items = [levelled(i) for i in items]
    items += [thinned(i) for i in items if i.dataset == "S3DIS"]
    predictors: dict = {}
    for net in args.networks.split(","):
        spec = NETWORKS[net]
        if spec == M6 and not (MODELS / "dgcnn_s3dis" / "model_6.t7").is_file():
            print(f"\n{net}: no weights on this machine, skipped")
            continue
        pools: dict[str, Pool] = {}
        rooms: list[str] = []
        for item in [colourless(i) for i in items] if net == "nocolour" else items:
            out = votes(item, spec, predictors, before, after)
            assert item.scan.labels is not None
            pool = pools.setdefault(f"{item.dataset} {item.split}", Pool())
            pool.add(item.name, item.scan.labels, out)
            if item.dataset == "ScanNet" and net == "bundled":
                rooms.append(room_row(item, out))
        for title, pool in pools.items():
            print_pool(f"{net}, {title}", pool)
        if rooms:
            print("\n### ScanNet rooms from the bundled network's labels\n")
            print("| scan | true height | before | after | seen floor | floor area, true labels "
                  "| before | after |")  # fmt: skip
            print("|---|---|---|---|---|---|---|---|")
            print("\n".join(rooms))
    if args.speed:
        speed()


def room_row(item: Item, out: dict[str, np.ndarray]) -> str:
    """One table row: true, before and after ceiling height and floor area."""
    g = geometry_output("default", item)
    height, seen = true_rooms(item.scan)
    assert item.scan.labels is not None
    _, area = layout_rooms(item, item.scan.labels, None)  # the truth's own walls
    h0, a0 = layout_rooms(item, out["before"], None)
    h1, a1 = layout_rooms(item, out["after"], g.get("structure"))

    def h(v: float | None) -> str:
        return "-" if v is None else f"{v:.3f}"

    def pct(v: float) -> str:
        return f"{v:.2f} ({100 * (v - area) / area:+.1f} %)"

    return (f"| {item.name} | {h(height)} | {h(h0)} | {h(h1)} | {seen:.2f} | {area:.2f} | "
            f"{pct(a0)} | {pct(a1)} |")  # fmt: skip


if __name__ == "__main__":
    main()
