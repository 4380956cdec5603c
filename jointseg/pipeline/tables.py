"""The paper's evaluation tables from pipeline metrics: Table 1 (per-class IoU per room, network
row and fused row) and Table 2 (mIoU and mAcc per room), as rows, aligned text and CSV."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from jointseg.classes import CLASS_NAMES
from jointseg.metrics import SegmentationMetrics

#: Column heads of Table 1, abbreviated as in the paper.
CLASS_HEADS: tuple[str, ...] = (
    "ceil.",
    "floor",
    "wall",
    "beam",
    "col.",
    "wind.",
    "door",
    "table",
    "chair",
    "sofa",
    "book.",
    "board",
    "clut.",
)
#: The rows each room gets, and the metrics they come from.
METHODS: tuple[str, ...] = ("network", "fused")

Cell = str | float | None


@dataclass(frozen=True)
class RoomScores:
    """One evaluated scan: its name and the metrics of each method."""

    name: str
    metrics: dict[str, SegmentationMetrics]


def _mean(values: list[float | None]) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def table1(rooms: Sequence[RoomScores]) -> tuple[list[str], list[list[Cell]]]:
    """Per-class IoU per room and method; the last rows average each class over the rooms.

    Returns
    -------
    header : list of str
    rows : list of list
        ``[room, method, iou_ceiling, ..., iou_clutter]``, None for a class absent from the
        room (neither in its ground truth nor predicted).
    """
    header = ["room", "method", *CLASS_HEADS]
    rows: list[list[Cell]] = []
    for room in rooms:
        for method in METHODS:
            iou = room.metrics[method].per_class_iou
            rows.append([room.name, method, *(iou[c] for c in CLASS_NAMES)])
    if len(rooms) > 1:
        for method in METHODS:
            means = [
                _mean([r.metrics[method].per_class_iou[c] for r in rooms]) for c in CLASS_NAMES
            ]
            rows.append(["mean", method, *means])
    return header, rows


def table2(rooms: Sequence[RoomScores]) -> tuple[list[str], list[list[Cell]]]:
    """mIoU and mAcc per room and method; the last rows are their means over the rooms."""
    header = ["room", "method", "mIoU", "mAcc"]
    rows: list[list[Cell]] = []
    for room in rooms:
        for method in METHODS:
            m = room.metrics[method]
            rows.append([room.name, method, m.miou, m.macc])
    if len(rooms) > 1:
        for method in METHODS:
            rows.append(
                [
                    "mean",
                    method,
                    _mean([r.metrics[method].miou for r in rooms]),
                    _mean([r.metrics[method].macc for r in rooms]),
                ]
            )
    return header, rows


def format_score(value: float | None) -> str:
    """A score as the paper's tables print it: three decimals, '/' where undefined."""
    return "/" if value is None else f"{value:.3f}"


def _cell(value: Cell, missing: str) -> str:
    if value is None:
        return missing
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


def format_table(header: Sequence[str], rows: Sequence[Sequence[Cell]]) -> str:
    """Aligned plain text, three decimals, '/' for absent classes (as the paper prints them)."""
    cells = [list(header)] + [[_cell(v, "/") for v in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    lines = []
    for i, row in enumerate(cells):
        # room and method left-aligned, numbers right-aligned
        text = [
            c.ljust(w) if j < 2 else c.rjust(w)
            for j, (c, w) in enumerate(zip(row, widths, strict=True))
        ]
        lines.append("  ".join(text).rstrip())
        if i == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def to_csv(header: Sequence[str], rows: Sequence[Sequence[Cell]]) -> str:
    """CSV text; absent classes are empty cells, numbers keep full precision."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow(["" if v is None else v for v in row])
    return buffer.getvalue()
