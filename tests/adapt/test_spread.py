"""Corrections that spread inside a scan (issue 66, point 3): half of a room's beam segments
clicked, the proposal finds beams among the rest and touches nothing the user corrected."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jointseg.adapt.spread import propose
from jointseg.io import read_scan
from jointseg.labels.edits import apply_edits, parse_edits, version_labels
from jointseg.labels.version import machine_labels
from jointseg.pipeline import load_predictor
from jointseg.pipeline.config import PipelineConfig
from jointseg.synth import make_room
from tests.adapt.conftest import BEAM, ROOM, beam_segments


def test_half_the_beams_clicked_propose_the_other_half(corrected: Path) -> None:
    result = read_scan(corrected.with_name("room.ply"))  # version 0: the machine's labels
    truth = make_room(ROOM, points=40_000).labels
    assert truth is not None
    seg = np.asarray(result.fields["segment"], dtype=np.int64)
    beams = beam_segments(seg, truth)
    clicked, rest = beams[::2], beams[1::2]
    assert len(rest) >= 2
    user = np.where(np.isin(seg, clicked), BEAM, -1).astype(np.int16)
    half = result.with_fields(user_label=user)
    proposal = propose(half, load_predictor(PipelineConfig().network))
    assert len(proposal.segments) > 0
    assert not np.isin(proposal.segments, clicked).any()  # what the user did stays
    assert set(proposal.labels.tolist()) == {BEAM}  # only what the user taught
    found = np.isin(rest, proposal.segments).mean()
    right = np.isin(proposal.segments, beams).mean()
    assert found >= 0.5 and right >= 0.7, (found, right)
    # accepting it is an ordinary edit list: the next version holds the proposed beams
    machine = machine_labels(half)
    outcome = apply_edits(parse_edits({"edits": proposal.edits()}), machine_labels=machine,
                          user_label=user, segment=seg, xyz=result.xyz)  # fmt: skip
    labels = version_labels(machine, outcome.user_label)
    assert (labels[np.isin(seg, proposal.segments)] == BEAM).all()


def test_nothing_corrected_proposes_nothing(corrected: Path) -> None:
    result = read_scan(corrected.with_name("room.ply"))
    proposal = propose(result, load_predictor(PipelineConfig().network))
    assert len(proposal.segments) == 0 and proposal.edits() == []
