"""Label edits of the viewer without a browser: every row edited, the sample and counts following,
undo and redo exact; selections as edits of the whole result (issue 63)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jointseg.io import read_scan
from web.editing import LabelEdits, editable, read_columns, status_line
from web.scene import load_scene
from web.selection import inside_lasso, of_region, of_segment
from web.sources import DirectorySource, LabelsInfo


def test_a_segment_edit_covers_every_row_and_undo_redo_restore_it(results: Path) -> None:
    path = results / "labelled.ply"
    shared = load_scene(path, max_points=1500)  # a sample: edits must still cover every row
    data = editable(shared)
    columns = read_columns(path)
    scan = read_scan(path)
    assert np.array_equal(columns.segment, scan.fields["segment"])
    edits = LabelEdits(data, columns, LabelsInfo())
    row = 0
    seg = int(data.segments[row])
    members = scan.fields["segment"] == seg
    target = next(c for c in range(13) if not np.all(scan.fields["fused_label"][members] == c))
    before = data.counts["fused"].copy()
    edits.apply(of_segment(data, row).edit(target))
    expected = before.copy()
    for cls in scan.fields["fused_label"][members]:
        expected[cls] -= 1
    expected[target] += int(members.sum())
    assert np.array_equal(data.counts["fused"], expected)
    assert np.all(edits.labels[members] == target)
    assert np.all(data.fused[data.segments == seg] == target)
    assert not np.array_equal(shared.fused, data.fused)  # the shared scene is untouched
    assert edits.edit_list() is not None and edits.edit_list().edits[0].segments == [seg]
    edits.undo()
    assert np.array_equal(data.counts["fused"], before)
    assert np.array_equal(edits.labels, scan.fields["fused_label"])
    assert np.array_equal(data.fused, shared.fused)
    assert edits.edit_list() is None
    edits.redo()
    assert np.array_equal(data.counts["fused"], expected)
    assert "1 unsaved edit" in status_line(edits.info, edits.unsaved)


def test_a_region_is_a_box_of_the_file_holding_exactly_its_points(results: Path) -> None:
    path = results / "labelled.ply"
    data = editable(load_scene(path, max_points=1500))
    columns = read_columns(path)
    heights = (0.5, 1.0)
    chosen = of_region(data, columns, None, heights, "the slice")
    assert chosen is not None and "box" in chosen.part
    lo, hi = np.asarray(chosen.part["box"]["min"]), np.asarray(chosen.part["box"]["max"])
    in_box = np.all((columns.xyz >= lo) & (columns.xyz <= hi), axis=1)
    from web.clipping import ClipFrame

    wanted = ClipFrame.of(data).kept(data.shown_xyz(columns.xyz), None, heights)
    assert wanted.any() and np.array_equal(in_box, wanted)


def test_a_lasso_holds_the_points_inside_its_outline_at_any_depth() -> None:
    eye = np.zeros(3)
    # a square seen straight down the x axis: corners at (1, +-1, +-1)
    rays = np.array([[1.0, -1, -1], [1, 1, -1], [1, 1, 1], [1, -1, 1]])
    points = np.array([[2.0, 0, 0], [5, 4, 4], [5, 6, 0], [-2, 0, 0], [1, 0.9, 0.9]])
    assert inside_lasso(points, eye, rays).tolist() == [True, True, False, False, True]


def test_a_folder_refuses_to_save_saying_why(results: Path) -> None:
    from jointseg.exceptions import JobStateError
    from jointseg.labels.edits import parse_edits

    source = DirectorySource(results)
    assert source.labels("labelled").refusal is not None
    with pytest.raises(JobStateError, match="keeps no label versions"):
        source.save_edits(
            "labelled", parse_edits({"edits": [{"segments": [0], "label": 1}]}), if_match=None
        )


def test_an_object_and_a_lasso_cover_every_row_of_the_result(jobs: Path) -> None:
    from web.selection import of_lasso, of_object

    path = jobs / "room.ply"
    data = editable(load_scene(path, max_points=5000))
    columns = read_columns(path)
    assert data.instance is not None and columns.instance is not None
    row = int(np.flatnonzero(data.instance >= 0)[0])
    chosen = of_object(data, columns, row)
    assert chosen is not None
    wanted = np.flatnonzero(columns.instance == data.instance[row])
    assert chosen.part["points"] == wanted.tolist() and wanted.size > np.sum(
        data.instance == data.instance[row]
    )  # more than the points drawn
    # from high above the room, a square wider than it: every row, in the panel at x = 10
    eye = np.array([10.0, 0.0, 100.0])
    rays = np.array([[-1.0, -1, -10], [1, -1, -10], [1, 1, -10], [-1, 1, -10]])
    offsets = {"raw": np.zeros(3), "fused": np.array([10.0, 0.0, 0.0])}
    lasso = of_lasso(data, columns, eye, rays, offsets)
    assert lasso is not None and len(lasso.part["points"]) == columns.xyz.shape[0]
    # half of it (x < 10 in the fused panel's copy): exactly the rows on that side
    half = np.array([[-1.0, -1, -10], [0, -1, -10], [0, 1, -10], [-1, 1, -10]])
    left = of_lasso(data, columns, eye, half, offsets)
    shown = data.shown_xyz(columns.xyz)
    assert left is not None
    assert left.part["points"] == np.flatnonzero(shown[:, 0] < 0).tolist()
