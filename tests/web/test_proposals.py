"""Proposals from a tab's corrections without a browser (issue 66, point 3): a step of several
edits undone and withdrawn exactly; no corrections and no network told in words."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jointseg.exceptions import ConfigError
from jointseg.labels.edits import Edit
from web import proposals
from web.editing import LabelEdits, editable, read_columns
from web.proposals import NOTHING_CORRECTED, ProposalError, Snapshot, make_proposal
from web.scene import load_scene
from web.sources import LabelsInfo


def edits_of(path: Path) -> LabelEdits:
    return LabelEdits(editable(load_scene(path, max_points=1500)), read_columns(path), LabelsInfo())


def test_a_proposal_is_one_step_undone_whole_and_withdrawn_without_a_trace(results: Path) -> None:
    edits = edits_of(results / "labelled.ply")
    original, counts = edits.labels.copy(), edits.data.counts["fused"].copy()
    edits.apply(Edit(segments=[0], label=3))
    edits.undo()  # a redo history the withdrawn step must give back
    clicked, history = edits.labels.copy(), list(edits.undone)
    edits.apply_all([Edit(segments=[1, 2], label=5), Edit(segments=[3], label=6)])
    seg = edits.columns.segment
    assert (edits.labels[np.isin(seg, [1, 2])] == 5).all() and (edits.labels[seg == 3] == 6).all()
    saved = edits.edit_list()
    assert edits.unsaved == 1 and saved is not None and len(saved.edits) == 2  # one step, both
    edits.undo()
    assert np.array_equal(edits.labels, clicked) and edits.unsaved == 0
    edits.redo()
    edits.withdraw(history)
    assert np.array_equal(edits.labels, original)
    assert np.array_equal(edits.data.counts["fused"], counts)
    assert edits.undone == history


def snapshot(path: Path, edits: LabelEdits) -> Snapshot:
    return Snapshot(path, edits.columns, edits.labels.copy(), edits.edit_list(), None)


def test_no_corrections_and_no_network_are_told_in_words(
    results: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = results / "labelled.ply"
    edits = edits_of(path)
    with pytest.raises(ProposalError, match="Correct some segments first"):
        make_proposal(snapshot(path, edits))
    assert "Correct some segments first" in NOTHING_CORRECTED

    def no_network(config: object) -> None:
        raise ConfigError("network.weights: /nowhere.pt does not exist")

    monkeypatch.setattr(proposals, "_predictor", None)
    monkeypatch.setattr(proposals, "load_predictor", no_network)
    edits.apply(Edit(segments=[0], label=3))
    with pytest.raises(ProposalError, match="No network to propose with: network.weights"):
        make_proposal(snapshot(path, edits))
