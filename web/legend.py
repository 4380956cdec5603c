"""The viewer's side tables as small HTML snippets: class legend and per-class IoU.

Pure functions of counts and the report, so their content is tested without a browser.
"""

from __future__ import annotations

from html import escape
from typing import Any

import numpy as np

from jointseg.classes import CLASS_NAMES, NUM_CLASSES, PALETTE, UNLABELLED_COLOUR

_TABLE = 'style="width:100%;border-collapse:collapse;font-size:0.8em"'
_CELL = 'style="padding:1px 4px;text-align:right"'
_LEFT = 'style="padding:1px 4px;text-align:left"'


def present_classes(counts: dict[str, np.ndarray]) -> list[int]:
    """Classes (0..12, and -1 for unlabelled) with any point in any of the label sets."""
    total = np.sum(list(counts.values()), axis=0)
    present = [c for c in range(NUM_CLASSES) if total[c] > 0]
    if total[NUM_CLASSES] > 0:
        present.append(-1)
    return present


def class_title(cls: int) -> str:
    """The legend name of a class index (-1 is ``unlabelled``)."""
    return "unlabelled" if cls < 0 else CLASS_NAMES[cls]


def swatch(cls: int) -> str:
    """A small square in the class's palette colour."""
    rgb = UNLABELLED_COLOUR if cls < 0 else tuple(int(v) for v in PALETTE[cls])
    return (
        f'<span style="display:inline-block;width:0.9em;height:0.9em;vertical-align:middle;'
        f'border:1px solid #888;background:rgb{rgb}"></span>'
    )


def legend_html(counts: dict[str, np.ndarray]) -> str:
    """The palette of the classes present with their full-resolution point counts.

    Parameters
    ----------
    counts : dict of str to ndarray of shape (NUM_CLASSES + 1,)
        Points per class for ``network``, ``fused`` and optionally ``truth``.
    """
    columns = [k for k in ("network", "fused", "truth") if k in counts]
    head = "".join(f"<th {_CELL}>{k}</th>" for k in columns)
    rows = []
    for cls in present_classes(counts):
        i = NUM_CLASSES if cls < 0 else cls
        cells = "".join(f"<td {_CELL}>{int(counts[k][i]):,}</td>" for k in columns)
        rows.append(f"<tr><td {_LEFT}>{swatch(cls)} {escape(class_title(cls))}</td>{cells}</tr>")
    return f"<table {_TABLE}><tr><th {_LEFT}>class</th>{head}</tr>{''.join(rows)}</table>"


def _score(value: Any) -> str:
    return "/" if value is None else f"{float(value):.3f}"


def iou_html(report: dict[str, Any] | None) -> str | None:
    """Per-class IoU of the network and the fused labels from a report's ``metrics``.

    Returns
    -------
    str or None
        None when the report has no metrics (the scan had no ground truth). Absent classes
        show ``/`` as in the paper's tables.
    """
    metrics = (report or {}).get("metrics")
    if not isinstance(metrics, dict) or "network" not in metrics or "fused" not in metrics:
        return None
    net = metrics["network"].get("per_class_iou") or {}
    fused = metrics["fused"].get("per_class_iou") or {}
    rows = []
    for cls, name in enumerate(CLASS_NAMES):
        a, b = net.get(name), fused.get(name)
        if a is None and b is None:
            continue
        gain = "" if a is None or b is None else f"{float(b) - float(a):+.3f}"
        rows.append(
            f"<tr><td {_LEFT}>{swatch(cls)} {name}</td><td {_CELL}>{_score(a)}</td>"
            f"<td {_CELL}>{_score(b)}</td><td {_CELL}>{gain}</td></tr>"
        )
    n_miou, f_miou = metrics["network"].get("miou"), metrics["fused"].get("miou")
    gain = "" if n_miou is None or f_miou is None else f"{float(f_miou) - float(n_miou):+.3f}"
    rows.append(
        f'<tr style="border-top:1px solid #888;font-weight:bold"><td {_LEFT}>mIoU</td>'
        f"<td {_CELL}>{_score(n_miou)}</td><td {_CELL}>{_score(f_miou)}</td>"
        f"<td {_CELL}>{gain}</td></tr>"
    )
    return (
        f"<table {_TABLE}><tr><th {_LEFT}>IoU</th><th {_CELL}>network</th>"
        f"<th {_CELL}>fused</th><th {_CELL}>gain</th></tr>{''.join(rows)}</table>"
    )


def confusion_html(truth: np.ndarray, fused: np.ndarray) -> str | None:
    """Ground truth (rows) against the fused labels (columns) of the points shown, each row in
    percent of its points; the diagonal is what the fusion got right. None without truth."""
    from jointseg.metrics import confusion_matrix

    keep = truth >= 0
    if not keep.any():
        return None
    cm = confusion_matrix(truth[keep], fused[keep])
    rows_present = [c for c in range(NUM_CLASSES) if cm[c].sum() > 0]
    cols_present = [c for c in range(NUM_CLASSES) if cm[:, c].sum() > 0]
    if cm[:, NUM_CLASSES].sum() > 0:
        cols_present.append(NUM_CLASSES)
    head = "".join(
        f'<th {_CELL} title="{escape(class_title(c if c < NUM_CLASSES else -1))}">'
        f"{swatch(c if c < NUM_CLASSES else -1)}</th>"
        for c in cols_present
    )
    body = []
    for r in rows_present:
        total = cm[r].sum()
        cells = []
        for c in cols_present:
            share = 100.0 * cm[r, c] / total
            tint = "rgba(26,152,80,{a:.2f})" if c == r else "rgba(214,39,40,{a:.2f})"
            colour = tint.format(a=min(share / 100.0, 1.0) * 0.8)
            text = f"{share:.0f}" if cm[r, c] else ""
            cells.append(f'<td {_CELL[:-1]};background:{colour}">{text}</td>')
        body.append(
            f"<tr><td {_LEFT}>{swatch(r)} {escape(class_title(r))}</td>{''.join(cells)}</tr>"
        )
    return (
        f"<table {_TABLE}><tr><th {_LEFT}>truth \\ fused %</th>{head}</tr>{''.join(body)}</table>"
    )
