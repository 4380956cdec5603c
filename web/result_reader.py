"""A result file as the viewer needs it: class counts of every point, and an even sample of rows.

The viewer shows at most a few million points per panel, but its legend counts every point. A
20 M-point result PLY is 1.3 GB (double xyz and a dozen other properties); reading it whole, as
:func:`jointseg.io.read_scan` does, takes seconds and gigabytes for columns the viewer never
looks at. So a binary PLY (what ``jointseg segment`` and the service write) is read block by
block into one reused buffer (:mod:`jointseg.io.formats.ply.blocks`): each block adds its labels to
the counts and hands over the sample rows that fall in it. Memory is one block plus the sample,
whatever the size of the file. Any other file (ASCII PLY, LAS, colour that is not 8-bit, ...) is
read whole with ``read_scan`` and sampled in the same way.

The sample takes one row from every run of ``stride`` consecutive rows, at a seeded random place
in the run. It therefore covers every part of the file, in whatever order the points are
stored, and it does not alias with a scanner's line length as a fixed stride could.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.exceptions import ScanFormatError
from jointseg.io import read_scan
from jointseg.io.columns import LABEL_NAMES, pick_colour_names, pick_name
from jointseg.io.formats.ply.blocks import VertexBlock, open_vertex_blocks

#: Result fields the viewer needs (written by jointseg.pipeline.outputs.annotate).
REQUIRED_FIELDS = ("network_label", "segment", "fused_label")
#: Read when present: colour by confidence and the picked point's confidence need it.
CONFIDENCE_FIELD = "network_confidence"
#: Read when present: a picked point's object.
INSTANCE_FIELD = "instance"
#: Bytes of file read per block: small enough that counting three columns of a block finds it in
#: the CPU cache (8 MiB measured fastest on the 2-core reference machine, 32 MiB 2x slower).
BLOCK_BYTES = 8 << 20


@dataclass(frozen=True, eq=False)
class ResultSample:
    """Some rows of a result file, and class counts of all of them.

    Attributes
    ----------
    total : int
        Points in the file.
    rows : ndarray of shape (M,), int64
        The sampled rows, ascending.
    xyz : ndarray of shape (M, 3), float64
    rgb : ndarray of shape (M, 3), uint8, or None
    network, fused, segments : ndarray of shape (M,), int32
    truth : ndarray of shape (M,), int32, or None
        Ground truth, values outside 0..12 as -1.
    confidence : ndarray of shape (M,), float32, or None
        The network's confidence in its label, when the file has it.
    instance : ndarray of shape (M,), int32, or None
        The object each point belongs to (-1: none), when the file has it.
    counts : dict of str to ndarray of shape (NUM_CLASSES + 1,), int64
        Points per class of every row for ``network``, ``fused`` and ``truth`` (when present);
        the last entry counts unlabelled points.
    """

    total: int
    rows: np.ndarray
    xyz: np.ndarray
    rgb: np.ndarray | None
    network: np.ndarray
    fused: np.ndarray
    segments: np.ndarray
    truth: np.ndarray | None
    counts: dict[str, np.ndarray]
    confidence: np.ndarray | None = None
    instance: np.ndarray | None = None


def class_counts(labels: np.ndarray) -> np.ndarray:
    """Points per class, (NUM_CLASSES + 1,) int64; the last entry counts unlabelled points
    (-1 and any value outside 0..12)."""
    shifted = np.clip(labels, -1, NUM_CLASSES).astype(np.intp) + 1
    raw = np.bincount(shifted, minlength=NUM_CLASSES + 2).astype(np.int64)
    return np.append(raw[1 : NUM_CLASSES + 1], raw[0] + raw[NUM_CLASSES + 1])


def sample_rows(total: int, budget: int, *, seed: int = 0) -> np.ndarray:
    """At most ``budget`` rows of ``total``, ascending: every row when they fit, else one random
    row from each run of ``ceil(total / budget)`` consecutive rows."""
    if budget < 1:
        raise ValueError(f"budget must be at least 1, got {budget}")
    if total <= budget:
        return np.arange(total, dtype=np.int64)
    stride = math.ceil(total / budget)
    starts = np.arange(0, total, stride, dtype=np.int64)
    rows = starts + np.random.default_rng(seed).integers(0, stride, starts.size)
    rows[-1] = min(int(rows[-1]), total - 1)  # the last run may be short
    return rows


def read_sample(path: str | os.PathLike[str], budget: int) -> ResultSample:
    """Class counts of every point of a result file and at most ``budget`` rows of it.

    Parameters
    ----------
    path : path
        A result written by ``jointseg segment`` or the job service (any format ``read_scan``
        reads; binary PLY is read block by block).
    budget : int
        Most rows sampled.

    Raises
    ------
    ScanFormatError
        When the file cannot be read or lacks the pipeline's fields.
    """
    path = Path(path)
    if path.suffix.lower() == ".ply":
        sample = _read_ply_blocks(path, budget)
        if sample is not None:
            return sample
    return _read_whole(path, budget)


def _missing(path: Path, names: list[str]) -> ScanFormatError | None:
    missing = [f for f in REQUIRED_FIELDS if f not in names]
    if not missing:
        return None
    return ScanFormatError(f"{path}: not a jointseg result, missing field(s) {', '.join(missing)}")


def _read_ply_blocks(path: Path, budget: int) -> ResultSample | None:
    """Counts and sample of a binary PLY, block by block; None when it needs the full reader
    (ASCII, list elements before the vertices, colour that is not 8-bit, labels that are not
    integers).
    """
    source = open_vertex_blocks(path)
    if source is None:
        return None
    record, names = source.dtype, source.names
    error = _missing(path, names)
    if error is not None:
        raise error
    colour = pick_colour_names(names)
    label = pick_name(names, LABEL_NAMES)
    if colour is not None and any(record[c] != np.dtype("u1") for c in colour):
        return None
    if label is not None and record[label].kind not in "iu":
        return None
    blocks = source.blocks(BLOCK_BYTES)  # checks the file's size first
    counted = {"network": "network_label", "fused": "fused_label"}
    if label is not None:
        counted["truth"] = label
    rows = sample_rows(source.count, budget)
    xyz = np.empty((rows.size, 3), dtype=np.float64)
    rgb = None if colour is None else np.empty((rows.size, 3), dtype=np.uint8)
    ints = {name: np.empty(rows.size, dtype=np.int32) for name in REQUIRED_FIELDS}
    truth = None if label is None else np.empty(rows.size, dtype=record[label].newbyteorder("="))
    # where each sampled column goes (every name is a different vertex property)
    targets: dict[str, np.ndarray] = {
        pick_name(names, (a,)) or a: xyz[:, i] for i, a in enumerate("xyz")
    }
    if rgb is not None and colour is not None:
        targets.update({channel: rgb[:, i] for i, channel in enumerate(colour)})
    targets.update(ints)
    if truth is not None and label is not None:
        targets[label] = truth
    confidence = None
    if CONFIDENCE_FIELD in names and record[CONFIDENCE_FIELD].kind == "f":
        confidence = np.empty(rows.size, dtype=np.float32)
        targets[CONFIDENCE_FIELD] = confidence
    instance = None
    if INSTANCE_FIELD in names and record[INSTANCE_FIELD].kind in "iu":
        instance = np.empty(rows.size, dtype=record[INSTANCE_FIELD].newbyteorder("="))
        targets[INSTANCE_FIELD] = instance
    counts = _gather(blocks, rows, targets, counted)
    _check_finite(path, xyz, rows)
    return ResultSample(
        total=source.count,
        rows=rows,
        xyz=xyz,
        rgb=rgb,
        network=ints["network_label"],
        fused=ints["fused_label"],
        segments=ints["segment"],
        truth=None if truth is None else _as_classes(truth),
        counts=counts,
        confidence=confidence,
        instance=None if instance is None else instance.astype(np.int32),
    )


def _gather(
    blocks: Iterator[VertexBlock],
    rows: np.ndarray,
    targets: dict[str, np.ndarray],
    counted: dict[str, str],
) -> dict[str, np.ndarray]:
    """Fill ``targets`` (column name -> values at ``rows``) from every block, and return the
    class counts of the ``counted`` columns (key -> column name) over every vertex."""
    counts = {key: np.zeros(NUM_CLASSES + 1, np.int64) for key in counted}
    names = list(targets)
    for block in blocks:
        for key, name in counted.items():
            counts[key] += class_counts(block.column(name))
        lo, hi = np.searchsorted(rows, (block.start, block.start + len(block.records)))
        part = block.take(rows[lo:hi] - block.start, names)
        for name, out in targets.items():
            out[lo:hi] = part[name]
    return counts


def _as_classes(labels: np.ndarray) -> np.ndarray:
    """Labels as int32 with every value outside 0..12 as -1 (as jointseg.io reads them)."""
    labels = labels.astype(np.int32)
    labels[(labels < 0) | (labels >= NUM_CLASSES)] = -1
    return labels


def _check_finite(path: Path, xyz: np.ndarray, rows: np.ndarray) -> None:
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        raise ScanFormatError(
            f"{path}: vertex {int(rows[np.argmax(bad)]):,} has a non-finite coordinate"
        )


def _read_whole(path: Path, budget: int) -> ResultSample:
    """Counts and sample of a file read whole with ``read_scan``."""
    scan = read_scan(path)
    error = _missing(path, list(scan.fields))
    if error is not None:
        raise error
    network = np.asarray(scan.fields["network_label"])
    fused = np.asarray(scan.fields["fused_label"])
    counts = {"network": class_counts(network), "fused": class_counts(fused)}
    if scan.labels is not None:
        counts["truth"] = class_counts(scan.labels)
    rows = sample_rows(len(scan), budget)
    confidence = scan.fields.get(CONFIDENCE_FIELD)
    instance = scan.fields.get(INSTANCE_FIELD)
    return ResultSample(
        total=len(scan),
        rows=rows,
        xyz=scan.xyz[rows],
        rgb=None if scan.rgb is None else scan.rgb[rows],
        network=network[rows].astype(np.int32),
        fused=fused[rows].astype(np.int32),
        segments=np.asarray(scan.fields["segment"])[rows].astype(np.int32),
        truth=None if scan.labels is None else _as_classes(scan.labels[rows]),
        counts=counts,
        confidence=None if confidence is None else np.asarray(confidence)[rows].astype(np.float32),
        instance=None if instance is None else np.asarray(instance)[rows].astype(np.int32),
    )
