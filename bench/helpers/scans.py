"""The scans the accuracy and fusion benchmarks score, and the network and geometry outputs on
them, cached under bench/_cache so that comparing fusion variants does not rerun networks.

The tuning scans, their variants and the cached outputs are the package's
(:mod:`jointseg.fitting`): `jointseg fit vote --cache bench/_cache` and these benchmarks read
the same files. Held-out synthetic scans use seeds no training run uses; calibration rooms
seeds no benchmark holds out. Real labelled scans belong to a dataset (their folder) and a room
(ScanNet's re-scans share one), and are split per dataset into judging and tuning rooms.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np

from helpers.inputs import CACHE
from jointseg.fitting import outputs
from jointseg.fitting.outputs import INFERENCE_VERSION, STRUCTURE_VERSION, cached, network_name
from jointseg.fitting.outputs import weights_fingerprint as weights_fingerprint
from jointseg.fitting.scans import THIN, colourless, content_key, room_of, synthetic_rooms, thinned
from jointseg.fitting.scans import TuningScan as Item
from jointseg.fitting.vote import structure_hint
from jointseg.geometry import GeometryParams
from jointseg.io import read_scan
from jointseg.scan import Scan
from jointseg.synth import make_floor, make_room
from jointseg.training.data import stable_order

__all__ = [
    "CACHE",
    "INFERENCE_VERSION",
    "STRUCTURE_VERSION",
    "THIN",
    "Item",
    "cached",
    "calibration_rooms",
    "colourless",
    "content_key",
    "geometry_output",
    "held_out",
    "load_items",
    "network_name",
    "network_output",
    "room_of",
    "structure_hint",
    "thinned",
]

# Seeds far from the training (1000+, 3000+) and validation (2000+) seeds.
ROOM_SEEDS = 5000
FLOOR_SEEDS = 6000
#: Seeds of the rooms the learned vote is fitted on: no benchmark holds them out.
CALIBRATION_SEED = 7000
#: ScanNet rooms judged (every re-scan of a room on one side): the three the bundled RandLA-Net
#: never trained on (scene0002 and scene0007 excluded, scene0005 its validation room).
SCANNET_JUDGES = ("scene0002", "scene0005", "scene0007")
#: Folder (or file stem) -> dataset name in the tables.
DATASET_NAMES = {"s3dis_area6": "S3DIS", "scannet": "ScanNet", "s3dis_fragment": "S3DIS fragment"}

#: Geometry settings compared (name -> GeometryParams overrides).
GEOMETRY: dict[str, dict[str, Any]] = {
    "default": {},
    "colour0.6": {"colour_scale": 0.6},
    "colour0.6-min10": {"colour_scale": 0.6, "min_region_points": 10},
    "voxel1.5": {"voxel_factor": 1.5},
    "colour0.4": {"colour_scale": 0.4},
    "colour0.4-min10": {"colour_scale": 0.4, "min_region_points": 10},
    "colour0.3-min10": {"colour_scale": 0.3, "min_region_points": 10},
}


def held_out(rooms: int, floors: int, points: int) -> list[tuple[str, Scan]]:
    """Synthetic scans with seeds no training run uses; yaw drawn from the seed."""
    scans = []
    for i in range(rooms):
        shape: Literal["box", "L"] = "L" if i % 2 else "box"
        scans.append(
            (
                f"room {ROOM_SEEDS + i} ({shape})",
                make_room(ROOM_SEEDS + i, points=points, shape=shape),
            )
        )
    for i in range(floors):
        scans.append((f"floor {FLOOR_SEEDS + i}", make_floor(FLOOR_SEEDS + i, points=points * 3)))
    return scans


def calibration_rooms(rooms: int, floors: int, points: int) -> list[Item]:
    """Synthetic rooms and floors with seeds no benchmark holds out (the vote's tuning rooms)."""
    return synthetic_rooms(CALIBRATION_SEED, rooms, floors, points)


def dataset_of(path: Path) -> str:
    """The dataset a scan belongs to, by its folder (or, for a lone file, its stem)."""
    key = path.parent.name if path.parent.name in DATASET_NAMES else path.stem
    return DATASET_NAMES.get(key, path.parent.name)


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


def network_output(
    spec: str, item: Item, predictors: dict[str, Any]
) -> tuple[np.ndarray, np.ndarray]:
    """Labels and probabilities of network ``spec`` ("backend[:weights]") on a scan, cached."""
    return outputs.network_output(spec, item, predictors, CACHE)


def geometry_output(name: str, item: Item) -> dict[str, np.ndarray]:
    """Segments and main-plane ids of geometry setting ``name`` on a scan, cached."""
    return outputs.geometry_output(item, GeometryParams(**GEOMETRY[name]), CACHE)
