"""Legend and score tables: the palette, the counts and the report's per-class IoU."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.classes import CLASS_NAMES, PALETTE
from web.legend import class_title, iou_html, legend_html, present_classes
from web.result_reader import class_counts


def test_legend_lists_present_classes_with_palette_and_counts() -> None:
    counts = {
        "network": class_counts(np.array([2, 2, 2, 5, 5, 12])),
        "fused": class_counts(np.array([2, 2, 2, 2, 5, 5])),
        "truth": class_counts(np.array([2, 2, 1, -1, 5, 5])),
    }
    assert present_classes(counts) == [1, 2, 5, 12, -1]
    html = legend_html(counts)
    for cls in (1, 2, 5, 12):
        assert CLASS_NAMES[cls] in html
        assert f"rgb{tuple(int(v) for v in PALETTE[cls])}" in html
    assert "ceiling" not in html and "unlabelled" in html
    # wall row: network 3, fused 4, truth 2
    wall = html.split("wall</td>")[1].split("</tr>")[0]
    assert [c.split(">")[-1] for c in wall.split("</td>")[:3]] == ["3", "4", "2"]
    assert class_title(-1) == "unlabelled" and class_title(0) == "ceiling"


@pytest.mark.slow
def test_iou_table_from_a_real_report(results: Path) -> None:
    report = json.loads((results / "labelled.report.json").read_text())
    html = iou_html(report)
    assert html is not None
    net = report["metrics"]["network"]
    fused = report["metrics"]["fused"]
    assert f"{net['miou']:.3f}" in html and f"{fused['miou']:.3f}" in html
    for name, value in net["per_class_iou"].items():
        if value is not None:
            assert name in html
    # absent from ground truth and both predictions: no row
    for name in CLASS_NAMES:
        if net["per_class_iou"][name] is None and fused["per_class_iou"][name] is None:
            assert f"{name}</td>" not in html


def test_no_iou_table_without_ground_truth(results: Path) -> None:
    report = json.loads((results / "unlabelled.report.json").read_text())
    assert iou_html(report) is None
    assert iou_html(None) is None


def test_confusion_table_rows_are_truth_in_percent() -> None:
    from web.legend import confusion_html

    truth = np.array([1, 1, 1, 1, 2, 2, -1])
    fused = np.array([1, 1, 1, 2, 2, 2, 5])
    html = confusion_html(truth, fused)
    assert html is not None
    floor_row = html.split("floor</td>")[1].split("</tr>")[0]
    assert ">75<" in floor_row and ">25<" in floor_row
    wall_row = html.split("wall</td>")[1].split("</tr>")[0]
    assert ">100<" in wall_row
    assert "window" not in html  # a prediction only on a point without truth is not counted
    assert confusion_html(np.full(3, -1), np.zeros(3, int)) is None
