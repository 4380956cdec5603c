"""The labelled tuning scans a fit reads, and the variants made of them (thinned, without
colour, a floor slice), each with a content key (for caches) and a provenance record.

Why the variants are made here, not stored: a thinned or colour-free copy is a function of the
scan, so the record names the file it came from and the rule, and a refit makes the same copy.
"""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.fitting.provenance import ScanRecord, arrays_sha256, file_sha256
from jointseg.scan import Scan

#: Thinned copies of real rooms: one point per cell of this side (m), the sparser segments of
#: another building's scanner (issue 43: a held-out S3DIS room at 3.3 cm lost 3.4 points).
THIN = 0.033
#: Height of the band above the floor a slice keeps (m): the S3DIS fragment is such a slice.
SLICE_HEIGHT = 1.0
#: How a dataset's scans are made from its files: as read, thinned to THIN, without colour,
#: or the bottom SLICE_HEIGHT metres.
Variant = Literal["as is", "thinned", "no colour", "slice"]


@dataclass
class TuningScan:
    """One labelled scan and where it belongs."""

    name: str
    scan: Scan
    key: str  # content hash for the caches
    split: str = "tune"  # "judge", "tune", "synthetic" or "calibration" (the benchmarks' word)
    dataset: str = "synthetic"
    room: str = ""  # scans of one room share it (ScanNet re-scans)
    record: ScanRecord | None = None


def content_key(*parts: object) -> str:
    """A short hash of the parts (arrays by their bytes): the caches' key of a scan."""
    h = hashlib.sha1()
    for p in parts:
        h.update(p.tobytes() if isinstance(p, np.ndarray) else repr(p).encode())
    return h.hexdigest()[:16]


def room_of(stem: str) -> str:
    """The room a scan shows: ScanNet's ``sceneNNNN_MM`` re-scans share ``sceneNNNN``."""
    return re.sub(r"^(scene\d{4})_\d{2}$", r"\1", stem)


def scan_files(paths: list[Path]) -> list[Path]:
    """The scan files named: each file itself, each folder's readable scan files (sorted); a
    path that is neither, or a folder without scans, is a ConfigError naming it."""
    from jointseg.io.formats import READ_EXTENSIONS

    files: list[Path] = []
    for path in paths:
        if path.is_dir():
            found = sorted(
                p for p in path.iterdir() if p.is_file() and p.suffix.lower() in READ_EXTENSIONS
            )
            if not found:
                raise ConfigError(f"tuning scans {path}: a folder without scan files")
            files += found
        elif path.is_file():
            files.append(path)
        else:
            raise ConfigError(f"tuning scans {path}: no such file or folder")
    return files


def named_scan_files(paths: list[Path], base: Path) -> list[tuple[Path, str]]:
    """:func:`scan_files` of ``paths`` relative to ``base``, each with the name a record
    gives it: the path as the plan wrote it (a folder's files under the folder's name)."""
    out = []
    for given in paths:
        for path in scan_files([base / given]):
            out.append((path, str(given if path == base / given else given / path.name)))
    return out


def read_labelled(path: Path, dataset: str, shown: str | None = None) -> TuningScan:
    """A labelled scan file as a tuning scan of ``dataset``; ``shown`` is the path the record
    names (as the plan gave it). A scan without labels is a ConfigError naming the file."""
    from jointseg.io import read_scan

    scan = read_scan(path)
    if scan.labels is None:
        raise ConfigError(f"tuning scan {path}: no label field (a fit needs labelled scans)")
    record = ScanRecord(
        dataset=dataset, name=path.stem, path=shown or str(path), sha256=file_sha256(path)
    )
    key = content_key(scan.xyz, scan.labels)
    return TuningScan(path.stem, scan, key, "tune", dataset, room_of(path.stem), record)


def _derived(
    item: TuningScan, scan: Scan, name: str, key: str, dataset: str, made: str
) -> TuningScan:
    record = item.record
    if record is not None:
        record = record.model_copy(update={"dataset": dataset, "name": name, "made": made})
    return TuningScan(name, scan, key, item.split, dataset, item.room, record)


def _subset(scan: Scan, keep: np.ndarray) -> Scan:
    return Scan(
        xyz=scan.xyz[keep],
        rgb=None if scan.rgb is None else scan.rgb[keep],
        labels=None if scan.labels is None else scan.labels[keep],
    )


def thinned(item: TuningScan, dataset: str | None = None) -> TuningScan:
    """One point per THIN cell of a scan: a sparser room, as another building's scanner gives."""
    cells = np.floor(item.scan.xyz / THIN).astype(np.int64)
    _, first = np.unique(cells, axis=0, return_index=True)
    scan = _subset(item.scan, np.sort(first))
    dataset = dataset or f"{item.dataset} {THIN * 100:.1f} cm"
    key = content_key(item.key, "thin", THIN)
    return _derived(item, scan, f"{item.name} thin", key, dataset, f"thinned to {THIN} m cells")


def colourless(item: TuningScan, dataset: str | None = None) -> TuningScan:
    """The scan without its colour (what the colour-free network is for), in ``dataset``
    (default: the scan's own)."""
    scan = Scan(xyz=item.scan.xyz, rgb=None, labels=item.scan.labels)
    key = content_key(item.key, "no colour")
    return _derived(item, scan, item.name, key, dataset or item.dataset, "colour removed")


def floor_slice(item: TuningScan, dataset: str | None = None) -> TuningScan:
    """The bottom SLICE_HEIGHT metres of a scan, as a scan of its own in the same room (partial
    scans: the network and the geometry see only the slice)."""
    z = item.scan.xyz[:, 2]
    scan = _subset(item.scan, z < np.percentile(z, 2) + SLICE_HEIGHT)
    key = content_key(item.key, "slice", SLICE_HEIGHT)
    made = f"bottom {SLICE_HEIGHT} m"
    return _derived(item, scan, f"{item.name} slice", key, dataset or item.dataset, made)


VARIANTS = {"thinned": thinned, "no colour": colourless, "slice": floor_slice}


def variant(item: TuningScan, kind: Variant, dataset: str) -> TuningScan:
    """``item`` made into ``kind`` and put in ``dataset``."""
    if kind == "as is":
        return replace(item, dataset=dataset, record=_moved(item.record, dataset))
    return VARIANTS[kind](item, dataset)


def _moved(record: ScanRecord | None, dataset: str) -> ScanRecord | None:
    return None if record is None else record.model_copy(update={"dataset": dataset})


def synthetic_rooms(
    first_seed: int, rooms: int, floors: int, points: int, dataset: str = "synthetic"
) -> list[TuningScan]:
    """Generated labelled rooms (seeds ``first_seed``.., box and L in turn) and floors (seeds
    ``first_seed + 100``.., three times the points): tuning scans that need no files."""
    from jointseg.synth import make_floor, make_room

    out = []
    for i in range(rooms + floors):
        if i < rooms:
            seed = first_seed + i
            shape: Literal["box", "L"] = "L" if i % 2 else "box"
            name = f"room {seed} ({shape})"
            scan = make_room(seed, points=points, shape=shape)
            made = f"jointseg.synth.make_room({seed}, points={points}, shape={shape!r})"
        else:
            seed = first_seed + 100 + i - rooms
            name = f"floor {seed}"
            scan = make_floor(seed, points=3 * points)
            made = f"jointseg.synth.make_floor({seed}, points={3 * points})"
        sha = arrays_sha256(scan.xyz, scan.rgb, scan.labels)
        record = ScanRecord(dataset=dataset, name=name, sha256=sha, made=made)
        key = content_key(name, points)
        out.append(TuningScan(name, scan, key, "calibration", dataset, name, record))
    return out
