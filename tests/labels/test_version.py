"""A version's deliverables follow its labels: fused_label and user_label in PLY and LAS, the
LAS classification, objects and the report's labels section."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX
from jointseg.exceptions import ConfigError
from jointseg.io import read_scan, write_scan
from jointseg.labels.edits import apply_edits, parse_edits
from jointseg.labels.version import (
    check_result,
    corrected_points,
    version_layout,
    version_report,
    version_scan,
)
from jointseg.scan import Scan
from tests.support.cli import run_cli


def _tables_to_chairs(result: Scan) -> np.ndarray:
    tables = np.unique(result.fields["segment"][result.labels == CLASS_INDEX["table"]])
    body = {"edits": [{"segments": tables.tolist(), "label": "chair"}]}
    return apply_edits(
        parse_edits(body),
        machine_labels=result.fields["fused_label"],
        user_label=None,
        segment=result.fields["segment"],
        xyz=result.xyz,
    ).user_label


@pytest.mark.parametrize("suffix", [".ply", ".laz"])
def test_a_versions_file_carries_its_labels_and_the_users(
    result: Scan, tmp_path: Path, suffix: str
) -> None:
    user = _tables_to_chairs(result)
    path = write_scan(version_scan(result, user), tmp_path / f"v1{suffix}")
    back = read_scan(path)
    tables = result.labels == CLASS_INDEX["table"]
    assert tables.any()
    assert (back.fields["fused_label"][tables] == CLASS_INDEX["chair"]).all()
    np.testing.assert_array_equal(back.fields["fused_label"][~tables], result.labels[~tables])
    np.testing.assert_array_equal(back.fields["user_label"], user)
    if suffix == ".laz":
        classes = np.asarray(laspy.read(path).classification)
        assert (classes[tables] == 64 + CLASS_INDEX["chair"]).all()
        np.testing.assert_array_equal(classes[~tables], 64 + result.labels[~tables])


def test_a_versions_objects_are_found_from_its_labels(result: Scan) -> None:
    before = version_layout(result, result.fields["fused_label"], None).report
    user = _tables_to_chairs(result)
    labels = version_scan(result, user).fields["fused_label"]
    after = version_layout(result, labels, None).report
    kinds_before = [o.cls for o in before.objects]
    kinds_after = [o.cls for o in after.objects]
    assert "table" in kinds_before and "table" not in kinds_after
    assert kinds_after.count("chair") > kinds_before.count("chair")
    body = version_report(
        {"points": len(result)},
        after_layout := version_layout(result, labels, None),
        version=2,
        corrected=corrected_points(result, user),
    )
    assert body["labels"] == {
        "version": 2,
        "points_corrected": int((result.labels == CLASS_INDEX["table"]).sum()),
    }
    assert [o["cls"] for o in body["objects"]] == [o.cls for o in after_layout.report.objects]


def test_a_scan_that_is_no_result_is_refused(result: Scan) -> None:
    bare = Scan(result.xyz, fields={"segment": result.fields["segment"]})
    with pytest.raises(ConfigError, match="no fused_label field"):
        check_result(bare, name="scan.ply")


@pytest.mark.slow
def test_relabel_writes_every_deliverable_from_the_edits(result: Scan, tmp_path: Path) -> None:
    source = write_scan(result, tmp_path / "result.ply")
    tables = np.unique(result.fields["segment"][result.labels == CLASS_INDEX["table"]])
    edits = tmp_path / "edits.json"
    edits.write_text(json.dumps({"edits": [{"segments": tables.tolist(), "label": "chair"}]}))
    out, report, objects = tmp_path / "fixed.las", tmp_path / "report.json", tmp_path / "o.json"
    done = run_cli(
        "relabel", str(source), "--edits", str(edits), "-o", str(out),
        "--report-out", str(report), "--objects", str(objects), "--ifc", str(tmp_path / "m.ifc"),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    n_tables = int((result.labels == CLASS_INDEX["table"]).sum())
    assert f"{n_tables:,} labels changed by 1 edits" in done.stderr
    back = read_scan(out)
    assert (back.fields["user_label"] >= 0).sum() == n_tables
    assert json.loads(report.read_text())["labels"] == {"version": 1, "points_corrected": n_tables}
    kinds = [o["cls"] for o in json.loads(objects.read_text())["objects"]]
    assert "table" not in kinds and "chair" in kinds
    assert "IfcFurniture" in done.stderr


@pytest.mark.slow
def test_relabel_with_a_bad_edit_writes_nothing(result: Scan, tmp_path: Path) -> None:
    source = write_scan(result, tmp_path / "result.ply")
    edits = tmp_path / "edits.json"
    edits.write_text(json.dumps({"edits": [{"segments": [0], "label": "wal"}]}))
    out = tmp_path / "fixed.ply"
    done = run_cli("relabel", str(source), "--edits", str(edits), "-o", str(out))
    assert done.returncode == 2
    assert "edits[0].label: unknown class 'wal'" in done.stderr
    assert not out.exists()
