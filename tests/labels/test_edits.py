"""Edits by segment, point and box: checked whole before anything applies, applied in order."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX
from jointseg.exceptions import ConfigError
from jointseg.labels.edits import apply_edits, parse_edits, version_labels
from jointseg.scan import Scan


def _apply(result: Scan, body: dict, user: np.ndarray | None = None):
    return apply_edits(
        parse_edits(body),
        machine_labels=result.fields["fused_label"],
        user_label=user,
        segment=result.fields["segment"],
        xyz=result.xyz,
    )


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"edits": [{"segments": [1], "label": "wal"}]}, "edits[0].label: unknown class 'wal'"),
        ({"edits": [{"points": [1], "label": 13}]}, "edits[0].label: class 13 out of range"),
        ({"edits": [{"segments": [1], "points": [2], "label": 1}]}, "edits[0]"),
        ({"edits": [{"label": 1}]}, "exactly one of segments, points or box"),
        ({"edits": []}, "edits"),
        ({"edit": [{"segments": [1], "label": 1}]}, "edit"),
        ({"edits": [{"box": {"min": [0, 0, 2], "max": [1, 1, 1]}, "label": 1}]}, "edits[0].box"),
        ({"edits": [{"segments": ["x"], "label": 1}]}, "edits[0].segments[0]"),
    ],
)
def test_a_bad_edit_list_is_refused_naming_the_field(body: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace("[", r"\[").replace("]", r"\]")):
        parse_edits(body)


def test_a_segment_edit_gives_every_point_of_the_segment_the_class(result: Scan) -> None:
    segment = result.fields["segment"]
    target = int(np.bincount(segment).argmax())
    outcome = _apply(result, {"edits": [{"segments": [target], "label": "sofa"}]})
    inside = segment == target
    assert (outcome.user_label[inside] == CLASS_INDEX["sofa"]).all()
    assert (outcome.user_label[~inside] == -1).all()
    was_sofa = result.fields["fused_label"][inside] == CLASS_INDEX["sofa"]
    assert outcome.changed == int(inside.sum() - was_sofa.sum()) > 0
    assert outcome.touched == int(inside.sum())


def test_edits_apply_in_order_and_count_only_real_changes(result: Scan) -> None:
    machine = result.fields["fused_label"]
    same = int(np.flatnonzero(machine == CLASS_INDEX["wall"])[0])
    other = int(np.flatnonzero(machine == CLASS_INDEX["floor"])[0])
    body = {
        "edits": [
            {"points": [same, other], "label": "table"},
            {"points": [same], "label": "wall"},  # back to what the machine said: no change
        ]
    }
    outcome = _apply(result, body)
    assert outcome.user_label[same] == CLASS_INDEX["wall"]
    assert outcome.user_label[other] == CLASS_INDEX["table"]
    assert outcome.changed == 1 and outcome.touched == 2


def test_a_box_edit_takes_exactly_the_points_inside(result: Scan) -> None:
    lo = np.median(result.xyz, axis=0) - [1.0, 1.0, 5.0]  # a column through floor and ceiling
    hi = lo + [2.0, 2.0, 10.0]
    body = {"edits": [{"box": {"min": lo.tolist(), "max": hi.tolist()}, "label": 4}]}
    outcome = _apply(result, body)
    inside = np.all((result.xyz >= lo) & (result.xyz <= hi), axis=1)
    assert inside.any()
    np.testing.assert_array_equal(outcome.user_label == 4, inside)


def test_edits_build_on_earlier_versions_without_changing_their_array(result: Scan) -> None:
    first = _apply(result, {"edits": [{"points": [0, 1, 2], "label": "board"}]})
    kept = first.user_label.copy()
    second = _apply(result, {"edits": [{"points": [3], "label": "board"}]}, first.user_label)
    np.testing.assert_array_equal(first.user_label, kept)
    assert (second.user_label[:4] == CLASS_INDEX["board"]).all()
    labels = version_labels(result.fields["fused_label"], second.user_label)
    assert (labels[:4] == CLASS_INDEX["board"]).all()
    np.testing.assert_array_equal(labels[4:], result.fields["fused_label"][4:])


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ({"segments": [10**6], "label": 1}, r"edits\[1\].segments: segment 1000000 out of range"),
        ({"points": [-1], "label": 1}, r"edits\[1\].points: point -1 out of range"),
    ],
)
def test_an_id_out_of_range_refuses_the_whole_list(result: Scan, edit: dict, message: str) -> None:
    user = np.full(len(result), -1, np.int16)
    with pytest.raises(ConfigError, match=message):
        _apply(result, {"edits": [{"points": [0], "label": 1}, edit]}, user)
    assert (user == -1).all()
