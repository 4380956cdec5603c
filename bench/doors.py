"""Doors on ScanNet (issue 43's wall row): what the network's door labels and the geometry
can and cannot tell about a door leaf standing in its wall.

On the ScanNet judging scans most of the fused wall IoU still lost is door: leaves the vote
turns to wall, and wall the network calls door. This script measures, on the tuning and the
judging scans apart (bench/helpers/scans.py's split, levelled with the up axis forced to +z):

- the network's door labels: precision and recall against the truth, per split;
- the segments the network calls door (at least --share of at least 50 points) that the
  structure reading calls wall: their true wall, door and other points, and what the vote makes
  of them. Where such segments are mostly wall on the tuning scans, a vote fitted there turns
  them to wall, and real doors with them;
- the vote's pooled wall IoU, and the same with every point that is door in the truth or in
  the vote left out: what the wall row would read if the doors were told apart;
- a label-free door-leaf rule for scans without a seen ceiling (the reading applies it only
  with one): segments read as wall that are door-sized (jointseg.geometry.structure.door_sized,
  the scan's top standing for the storey's), each at least --top m high. It counts the true
  wall, door and other points such a rule would take out of the wall reading (the segments'
  fits over all points, the pipeline's over voxel centroids).

Network and geometry outputs are cached under bench/_cache (bench/helpers/scans.py).

    .venv/bin/python bench/doors.py [--networks bundled] [--share 0.6] [--top 0,1.5,1.8]
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import numpy as np
from helpers.inputs import SCANNET
from helpers.report import header
from helpers.scans import Item, geometry_output, load_items
from structure import NETWORKS, before_model, levelled, votes

from jointseg.classes import CLASS_INDEX
from jointseg.geometry import structure as reading
from jointseg.spacing import estimate_spacing

WALL, DOOR = CLASS_INDEX["wall"], CLASS_INDEX["door"]
#: Least points of a segment counted as the network's door.
MIN_POINTS = 50
SPLITS = ("tune", "judge")


def wall_door_other(truth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """True wall, door and other labelled points under ``mask``."""
    t = truth[mask]
    other = (t >= 0) & (t != WALL) & (t != DOOR)
    return np.array([np.sum(t == WALL), np.sum(t == DOOR), np.sum(other)])


def wall_counts(truth: np.ndarray, after: np.ndarray) -> np.ndarray:
    """Wall (tp, fn, fp) of the vote over the labelled points, and over those neither true nor
    voted door: shape (2, 3)."""
    counts = np.zeros((2, 3))
    labelled = truth >= 0
    for row, keep in enumerate((labelled, labelled & (truth != DOOR) & (after != DOOR))):
        t, a = truth[keep] == WALL, after[keep] == WALL
        counts[row] = (np.sum(t & a), np.sum(t & ~a), np.sum(~t & a))
    return counts


def door_segments(item: Item, labels: np.ndarray, share: float) -> np.ndarray:
    """Points of segments the network calls door that the structure reads as wall."""
    g = geometry_output("default", item)
    seg = g["segments"].astype(np.int64)
    n = int(seg.max()) + 1
    size = np.maximum(np.bincount(seg, minlength=n), 1)
    door = np.bincount(seg, labels == DOOR, n) / size
    wall = np.bincount(seg, g["structure"] == WALL, n) / size
    chosen = (door >= share) & (wall >= 0.5) & (size >= MIN_POINTS)
    return chosen[seg]


def door_rule_points(item: Item, min_top: float) -> np.ndarray:
    """Points of segments read as wall on a scan without a seen ceiling that a door-leaf rule
    without the ceiling's condition would take out of the wall reading."""
    g = geometry_output("default", item)
    seg = g["segments"].astype(np.int64)
    xyz = item.scan.xyz.astype(np.float64)
    found = reading.read_structure(xyz, seg, estimate_spacing(xyz))
    if found.floor_z is None or found.ceiling_z is not None:
        return np.zeros(len(seg), bool)
    s = reading._summarise(xyz, seg, int(seg.max()) + 1, np.random.default_rng(0))
    top = float(np.quantile(xyz[:, 2], 0.995))  # the reading's storey top without a ceiling
    sized = reading.door_sized(s, found.floor_z, top) & (s.z_high >= found.floor_z + min_top)
    return (sized & (found.kind == WALL))[seg] & found.on_surface


def network_rows(net: str, items: list[Item], share: float) -> None:
    """The network's door labels, its door segments read as wall, the vote's wall IoU."""
    before = before_model("4dc3e5d")
    predictors: dict = {}
    print(f"\n### {net}: the network's door labels and the segments it calls door\n")
    print("| split | scans | door precision | door recall | door segments read as wall: "
          "true wall / door / other | vote: wall on true wall / on true door "
          "| vote's wall IoU | without door points |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for split in SPLITS:
        chosen = [i for i in items if i.split == split]
        hits, seg_truth, seg_vote, walls = np.zeros(3), np.zeros(3), np.zeros(2), np.zeros((2, 3))
        for item in chosen:
            out = votes(item, NETWORKS[net], predictors, before)
            labels, after = out["network"], out["after"]
            truth = item.scan.labels
            assert truth is not None
            hits += (np.sum((labels == DOOR) & (truth == DOOR)), np.sum(labels == DOOR),
                     np.sum(truth == DOOR))  # fmt: skip
            mask = door_segments(item, labels, share)
            seg_truth += wall_door_other(truth, mask)
            seg_vote += (np.sum(mask & (truth == WALL) & (after == WALL)),
                         np.sum(mask & (truth == DOOR) & (after == WALL)))  # fmt: skip
            walls += wall_counts(truth, after)
        iou = walls[:, 0] / np.maximum(walls.sum(axis=1), 1)
        print(f"| {split} | {len(chosen)} | {hits[0] / max(hits[1], 1):.3f} | "
              f"{hits[0] / max(hits[2], 1):.3f} | {' / '.join(f'{v:.0f}' for v in seg_truth)} | "
              f"{seg_vote[0]:.0f} / {seg_vote[1]:.0f} | {iou[0]:.3f} | {iou[1]:.3f} |")  # fmt: skip


def rule_rows(items: list[Item], tops: list[float]) -> None:
    """What a door-leaf rule without a seen ceiling would take out of the wall reading."""
    print("\n### A door-leaf rule without a seen ceiling: points it would take out of the wall "
          "reading\n")  # fmt: skip
    print("| least top above the floor, m | split | true wall | true door | other |")
    print("|---|---|---|---|---|")
    for min_top in tops:
        for split in SPLITS:
            counts = np.zeros(3)
            for item in (i for i in items if i.split == split):
                assert item.scan.labels is not None
                counts += wall_door_other(item.scan.labels, door_rule_points(item, min_top))
            cells = " | ".join(f"{v:.0f}" for v in counts)
            print(f"| {min_top:g} | {split} | {cells} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--networks", default="bundled")
    parser.add_argument("--share", type=float, default=0.6)
    parser.add_argument("--top", default="0,1.5,1.8")
    parser.add_argument("--judge", type=int, default=10)
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    print(f"`{Path(sys.argv[0]).name} {' '.join(sys.argv[1:])}`")
    items = [levelled(i) for i in load_items([str(SCANNET)], args.judge, (0, 0, 0))]
    for net in args.networks.split(","):
        network_rows(net, items, args.share)
    rule_rows(items, [float(t) for t in args.top.split(",")])


if __name__ == "__main__":
    main()
