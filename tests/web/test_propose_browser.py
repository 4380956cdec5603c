"""Corrections that spread inside one scan, in Debian's headless chromium (issue 66, point 3):
room 4, whose beams the bundled network misses, with half its beam segments given *beam*; the
proposal appears as one step (drawn, counted), *Accept* keeps it, *Undo* takes it back whole,
and a second proposal discarded leaves the labels as they were.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jointseg.classes import CLASS_INDEX
from jointseg.io import read_scan
from tests.support.viewer_pages import wait_for
from tests.web.test_edit_labels_browser import fused_count, key_of
from tests.web.test_viewer_tools_browser import settled_view
from web.edit_controls import ACCEPT, DISCARD, PROPOSE, UNDO
from web.selection import Selection
from web.viewer import Viewer

BEAM = CLASS_INDEX["beam"]


def beam_segments(seg: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Segment ids whose points are mostly beam (the ground truth of the file)."""
    n = int(seg.max()) + 1
    beams = np.bincount(seg[(truth == BEAM) & (seg >= 0)], minlength=n)
    return np.flatnonzero(beams > 0.5 * np.maximum(np.bincount(seg[seg >= 0], minlength=n), 1))


def proposed(page: Any, view: Any) -> Any:
    """Press *Propose* and wait for the proposal shown; the proposal."""
    page.get_by_role("button", name=PROPOSE).click()
    page.get_by_text("Proposed", exact=False).first.wait_for(timeout=60_000)
    pending = view.editing.proposals.pending
    assert pending is not None
    return pending.proposal


def test_a_proposal_is_shown_accepted_undone_and_discarded(
    browser: Any, viewer: Viewer, jobs: Path, artifacts: Path
) -> None:
    scan = read_scan(jobs / "room.ply")
    seg = np.asarray(scan.fields["segment"], np.int64)
    assert scan.labels is not None
    beams = beam_segments(seg, scan.labels)
    assert len(beams) >= 4
    page, view = settled_view(browser, viewer, "room")
    try:
        assert view.editing.ui.propose.disabled  # nothing corrected yet
        with view._lock:  # the user's clicks on half the beams (the clicking has its own tests)
            view.editing.selection = Selection("beams", {"segments": beams[::2].tolist()})
        page.keyboard.press(key_of(BEAM))
        page.get_by_text("1 unsaved edit").wait_for(timeout=10_000)
        wait_for(lambda: not view.editing.ui.propose.disabled, what="Propose to be enabled")
        edits = view.editing.edits
        clicked, beam_count = edits.labels.copy(), fused_count(page, BEAM)

        proposal = proposed(page, view)
        rows = np.isin(seg, proposal.segments)
        assert len(proposal.segments) > 0 and not np.isin(proposal.segments, beams[::2]).any()
        labels = dict(zip(proposal.segments.tolist(), proposal.labels.tolist(), strict=True))
        wanted = np.vectorize(labels.get)(seg[rows])
        assert np.array_equal(edits.labels[rows], wanted)  # every row, drawn or not
        assert np.array_equal(edits.labels[~rows], clicked[~rows])
        moved = int(np.count_nonzero((wanted == BEAM) & (clicked[rows] != BEAM)))
        wait_for(lambda: fused_count(page, BEAM) == beam_count + moved, what="the legend")
        page.screenshot(path=str(artifacts / "proposal.png"))

        page.get_by_role("button", name=ACCEPT).click()
        page.get_by_text("2 unsaved edits").wait_for(timeout=10_000)
        assert np.array_equal(edits.labels[rows], wanted)
        page.get_by_role("button", name=UNDO).click()  # the whole proposal, one step
        page.get_by_text("1 unsaved edit").wait_for(timeout=10_000)
        assert np.array_equal(edits.labels, clicked)
        wait_for(lambda: fused_count(page, BEAM) == beam_count, what="the undo")

        proposed(page, view)
        page.get_by_role("button", name=DISCARD).click()
        page.get_by_text("Proposal discarded.").wait_for(timeout=10_000)
        assert np.array_equal(edits.labels, clicked)
        assert fused_count(page, BEAM) == beam_count and edits.unsaved == 1
    finally:
        page.close()
