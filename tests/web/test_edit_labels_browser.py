"""Correcting labels in the viewer, in Debian's headless chromium (issue 63): a segment clicked
takes a class from its number key, the legend's full-resolution count and the drawn class groups
follow at once, Ctrl+Z undoes and *Redo* re-applies; a folder of results refuses to save and
says why. Saving to the job service and reloading: tests/web/test_edit_labels_service.py.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jointseg.classes import CLASS_NAMES
from jointseg.io import read_scan
from tests.support.viewer_pages import wait_for
from tests.web.test_viewer_tools_browser import (
    BACK,
    aim,
    answer,
    clear_point,
    click_centre,
    settled_view,
    visible_rows,
)
from web.edit_controls import SHORTCUTS
from web.selection import SEGMENT
from web.viewer import Viewer

#: The fused column of the class legend in the control panel (not the overlay's copy).
FUSED_COUNT = """(name) => {
  for (const table of document.querySelectorAll('table')) {
    if (table.closest('#jointseg-overlay') || !table.rows.length) continue;
    const head = [...table.rows[0].cells].map(c => c.textContent.trim());
    const col = head.indexOf('fused');
    if (col < 0 || head[0] !== 'class') continue;
    for (const row of table.rows)
      if (row.cells[0].textContent.trim() === name)
        return Number(row.cells[col].textContent.replace(/,/g, ''));
    return 0;
  }
  return -1;
}"""


def fused_count(page: Any, cls: int) -> int:
    """The legend's fused count of class ``cls`` as the browser shows it (0: not listed)."""
    return int(page.evaluate(FUSED_COUNT, CLASS_NAMES[cls]))


def key_of(cls: int) -> str:
    """The key a user presses for class ``cls`` (Playwright's name for it)."""
    shortcut = SHORTCUTS[cls]
    return f"Shift+Digit{shortcut[-1]}" if shortcut.startswith("⇧") else f"Digit{shortcut}"


def drawn_in_class(view: Any, cls: int) -> int:
    """Points the fused panel's nodes of class ``cls`` hold (what the browser was sent)."""
    nodes = view.panels.nodes
    return sum(n.points.shape[0] for (p, c, _), n in nodes.items() if p == "fused" and c == cls)


def choose(page: Any, label: str, option: str) -> None:
    page.get_by_label(label, exact=True).click()
    page.get_by_role("option", name=option).click()


def test_a_clicked_segment_takes_a_class_by_key_and_undo_redo_follow(
    browser: Any, viewer: Viewer, jobs: Path
) -> None:
    page, view = settled_view(browser, viewer, "room")
    try:
        choose(page, "Select", SEGMENT)
        page.get_by_text("Click a point: its segment is selected.").wait_for(timeout=10_000)
        data = view.data
        first = clear_point(data, visible_rows(view, "fused"), BACK, 0.25)
        aim(page, view, "fused", first, BACK)
        click_centre(page)
        seg = int(answer(page, r"Selected: segment (\d+)").group(1))
        scan = read_scan(jobs / "room.ply")
        members = scan.fields["segment"] == seg
        labels = scan.fields["fused_label"][members]
        commonest = int(np.bincount(labels, minlength=13).argmax())
        target = 8 if commonest != 8 else 7  # chair, or table: a class with a plain digit key
        moved = int(np.count_nonzero(labels != target))
        assert moved > 0
        before, drawn_before = fused_count(page, target), drawn_in_class(view, target)
        sent = view.panels.shown  # the rows sent to the browser (None: all)
        shown = np.arange(data.xyz.shape[0]) if sent is None else sent
        in_seg = (data.segments[shown] == seg) & (data.fused[shown] != target)
        drawn_moved = int(np.count_nonzero(in_seg))
        assert before >= 0, "no class legend in the control panel"

        page.keyboard.press(key_of(target))
        wait_for(lambda: fused_count(page, target) == before + moved, what="the count to follow")
        edited = view.data
        assert np.all(edited.fused[edited.segments == seg] == target)
        assert drawn_in_class(view, target) == drawn_before + drawn_moved
        page.get_by_text("1 unsaved edit").wait_for(timeout=10_000)

        page.keyboard.press("Control+z")
        wait_for(lambda: fused_count(page, target) == before, what="the undo")
        assert drawn_in_class(view, target) == drawn_before
        page.get_by_text("no unsaved edits").wait_for(timeout=10_000)

        page.get_by_role("button", name="Redo").click()
        wait_for(lambda: fused_count(page, target) == before + moved, what="the redo")
        assert drawn_in_class(view, target) == drawn_before + drawn_moved

        # a folder of results keeps no versions: Save says so and the edit stays unsaved
        page.get_by_role("button", name="Save").click()
        page.get_by_text("keeps no label versions", exact=False).first.wait_for(timeout=10_000)
        page.get_by_text("1 unsaved edit").wait_for(timeout=10_000)
    finally:
        page.close()
