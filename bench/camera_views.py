"""Depth-camera views of the real rooms through the whole pipeline: what the vote gains there.

A depth camera delivers one view of a room, not the room: a wall, a desk, a corner, held at
however the user held it. Each real room (S3DIS Area_6, ScanNet; bench/helpers/scans.py's
split into tuning and judging rooms) gives ``--views`` views cut along a depth camera's frustum
(jointseg.synth.views: 58 x 45 deg, held 1.0-1.7 m up inside the room, pitched -25 to +10
deg, rolled up to 5 deg, the nearest surface per pixel), in the camera's frame (y down, z
forward). Each view goes through ``jointseg.pipeline.run`` with the default configuration (the
frame stage decides its up, as for a user's file) and the bundled network, and is scored
against the room's labels (jointseg.metrics: classes in the truth or the labels).

Per split and dataset: views, mean network and fused mIoU, the vote's mean gain, the views
losing more than half a point (issue 43's bar for whole scans) and the worst; the views whose
up the frame stage got more than 5 degrees wrong (against the room's labelled floor: a ScanNet
scan may lean off its file's z); and the views where the structure reading found a floor.
``--per-view`` lists every view.

    .venv/bin/python bench/camera_views.py [--views 3] [--splits tune,judge] [--per-view]
"""

from __future__ import annotations

import argparse
import logging
import zlib
from dataclasses import dataclass

import numpy as np
from helpers.inputs import AREA6, SCANNET
from helpers.report import LOSS_BAR, header
from helpers.scans import Item, load_items

from jointseg.classes import CLASS_INDEX
from jointseg.network import load
from jointseg.pipeline import run
from jointseg.pipeline.config import PipelineConfig
from jointseg.scan import Scan
from jointseg.synth.views import camera_view

#: Views whose decided up is further than this (degrees) from the truth count as mislevelled.
LEVEL_ERROR = 5.0
FLOOR = CLASS_INDEX["floor"]


@dataclass
class View:
    room: str
    dataset: str
    split: str
    index: int
    points: int
    network: float
    fused: float
    up_error: float  # degrees between the decided up and the true one
    floor: bool  # the structure reading found a floor level

    @property
    def gain(self) -> float:
        return 100 * (self.fused - self.network)


def room_up(room: Scan) -> np.ndarray:
    """The room's true up: its labelled floor's normal (a ScanNet scan may lean a few degrees
    off its file's z), else +z."""
    floor = room.xyz[room.labels == FLOOR] if room.labels is not None else room.xyz[:0]
    if len(floor) < 500:
        return np.array([0.0, 0.0, 1.0])
    _, _, vt = np.linalg.svd(floor - floor.mean(axis=0), full_matrices=False)
    return vt[2] * np.sign(vt[2, 2])


def views_of(item: Item, n: int, predictor: object) -> list[View]:
    """``n`` views of one room (its own generator: adding a room changes no other's views)."""
    room = item.scan
    true_up = room_up(room)
    rng = np.random.default_rng([7, zlib.crc32(item.name.encode())])
    out = []
    for i in range(n):
        view = camera_view(room, rng)
        if view is None:
            continue
        result = run(view.scan, PipelineConfig(), predictor=predictor)  # type: ignore[arg-type]
        m = result.metrics
        if m is None or m["network"].miou is None or m["fused"].miou is None:
            continue  # no labelled point in sight
        up = np.zeros(3) if result.frame is None else np.asarray(result.frame.up.up)
        cos = float(np.clip(up @ (view.rotation @ true_up), -1, 1))
        out.append(
            View(
                item.name,
                item.dataset,
                item.split,
                i,
                len(view.points),
                m["network"].miou,
                m["fused"].miou,
                float(np.degrees(np.arccos(cos))),
                result.geometry.floor_z is not None,
            )  # fmt: skip
        )
    return out


def table(views: list[View]) -> None:
    print("| split | dataset | views | network | fused | gain, mean | losing over 0.5 | worst "
          "| up off > 5 deg | floor read |")  # fmt: skip
    print("|---" * 10 + "|")
    for split in ("tune", "judge"):
        for dataset in ("S3DIS", "ScanNet"):
            sel = [v for v in views if v.split == split and v.dataset == dataset]
            if not sel:
                continue
            gains = np.array([v.gain for v in sel])
            print(
                f"| {split} | {dataset} | {len(sel)} | {np.mean([v.network for v in sel]):.3f} | "
                f"{np.mean([v.fused for v in sel]):.3f} | {gains.mean():+.2f} | "
                f"{int((gains < -LOSS_BAR).sum())} | {gains.min():+.2f} | "
                f"{sum(v.up_error > LEVEL_ERROR for v in sel)} | {sum(v.floor for v in sel)} |"
            )
    losing = [v for v in views if v.gain < -LOSS_BAR]
    if losing:
        mislevelled = sum(v.up_error > LEVEL_ERROR for v in losing)
        print(f"\nviews losing over {LOSS_BAR} points: {len(losing)}, {mislevelled} of them with "
              f"their up more than {LEVEL_ERROR:g} degrees off")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--views", type=int, default=3, help="views per room")
    parser.add_argument("--splits", default="tune,judge")
    parser.add_argument("--per-view", action="store_true")
    args = parser.parse_args()
    header("depth-camera views of the real rooms")
    logging.basicConfig(level=logging.ERROR)
    if not AREA6.is_dir() and not SCANNET.is_dir():
        raise SystemExit(f"no real rooms under {AREA6.parent}: this bench needs ../shared/data")
    predictor = load("randlanet")
    splits = args.splits.split(",")
    views: list[View] = []
    for item in load_items([str(AREA6), str(SCANNET)], 10, (0, 0, 0)):
        if item.split in splits:
            views += views_of(item, args.views, predictor)
    if args.per_view:
        print("| room | view | points | network | fused | gain | up off, deg | floor |")
        print("|---" * 8 + "|")
        for v in views:
            print(f"| {v.room} | {v.index} | {v.points:,} | {v.network:.3f} | {v.fused:.3f} | "
                  f"{v.gain:+.2f} | {v.up_error:.1f} | {'yes' if v.floor else 'no'} |")  # fmt: skip
        print()
    table(views)


if __name__ == "__main__":
    main()
