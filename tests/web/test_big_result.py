"""A result with more points than a panel shows, in the viewer and in Debian's headless chromium.

The viewer's cap is lowered to 20 000 points per panel, so a 300 000-point result stands in for
a 20 M-point one (2 M per panel) and the test stays fast. The result's rows are sorted along x,
so a loader that kept the first rows would show one end of the floor only.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy.spatial import cKDTree

from jointseg.io import read_scan, write_scan
from jointseg.scan import Scan
from jointseg.synth import make_floor
from tests.support.result_files import synthetic_result
from tests.support.shots import panel_spans, settled
from tests.support.viewer_pages import free_port, open_tab, view_of
from web.sources import DirectorySource
from web.viewer import Viewer

CAP = 20_000
POINTS = 300_000


@pytest.fixture(scope="module")
def big(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``big.ply``: a 6-room floor of 300 000 points as a result file, rows sorted along x."""
    folder = tmp_path_factory.mktemp("big_result")
    scan = make_floor(1, rooms=6, points=POINTS)
    order = np.argsort(scan.xyz[:, 0], kind="stable")
    fields = {k: v[order] for k, v in scan.fields.items()}
    assert scan.rgb is not None and scan.labels is not None
    ordered = Scan(scan.xyz[order], scan.rgb[order], scan.labels[order], fields)
    write_scan(synthetic_result(ordered), folder / "big.ply")
    return folder


@pytest.fixture(scope="module")
def capped(big: Path) -> Iterator[Viewer]:
    instance = Viewer(DirectorySource(big), port=free_port(), max_points=CAP)
    try:
        yield instance
    finally:
        instance.stop()


def columns(xyz: np.ndarray, size: float = 2.0) -> set[tuple[int, int]]:
    """The x-y columns of side ``size`` that hold any of the points."""
    return {(a, b) for a, b in np.floor(xyz[:, :2] / size).astype(int).tolist()}


def rows_of(points: np.ndarray, scan: Scan) -> np.ndarray:
    """The row of ``scan`` each of ``points`` (metres, absolute) is: its nearest point, which
    must lie within float32's rounding of the shown positions."""
    distance, rows = cKDTree(scan.xyz).query(points)
    assert distance.max() < 1e-4, distance.max()
    return np.asarray(rows)


def test_a_result_over_the_cap_shows_at_most_the_cap_spread_over_the_whole_scan(
    browser: Any, capped: Viewer, big: Path, artifacts: Path
) -> None:
    page = open_tab(browser, capped.link("big"))
    try:
        status = page.get_by_text("points shown")
        status.wait_for(timeout=60_000)
        image = settled(page)
        (artifacts / "viewer_big_capped.png").write_bytes(page.screenshot())
        assert len(panel_spans(image, 4)) == 4  # raw, network, fused, ground truth

        # the page says how many points it draws (the ceiling starts hidden) of the file's
        found = re.search(r"([\d,]+) of ([\d,]+) points shown", status.inner_text())
        assert found is not None, status.inner_text()
        drawn, total = (int(g.replace(",", "")) for g in found.groups())
        assert total == POINTS
        view = view_of(capped, "big")
        visible = [n for k, n in view.panels.nodes.items() if k[0] == "fused" and n.visible]
        assert drawn == sum(n.points.shape[0] for n in visible)

        # and sent at most the cap per panel: each panel's nodes hold the same shown points
        data = view.data
        assert data is not None
        shown = data.xyz.shape[0]
        assert CAP // 4 < drawn < shown <= CAP
        panels = {key for key, _, _ in view.panels.nodes}
        assert panels == {"raw", "network", "fused", "truth"}
        for panel in panels:
            clouds = [n.points for k, n in view.panels.nodes.items() if k[0] == panel]
            assert sum(c.shape[0] for c in clouds) == shown <= CAP
        raw = np.concatenate([n.points for k, n in view.panels.nodes.items() if k[0] == "raw"])
        assert np.array_equal(np.unique(raw, axis=0), np.unique(data.xyz, axis=0))

        # the shown points are real points of the file, with their own labels, taken from
        # every part of it: every tenth of the rows (the file is sorted along x) ...
        scan = read_scan(big / "big.ply")
        rows = rows_of(data.xyz.astype(np.float64) + data.centre, scan)
        assert np.array_equal(data.fused, scan.fields["fused_label"][rows])
        assert np.array_equal(data.network, scan.fields["network_label"][rows])
        per_tenth = np.bincount(rows * 10 // POINTS, minlength=10)
        assert per_tenth.min() > 0.03 * shown, per_tenth
        # ... and every 2 m x 2 m column of the floor with a hundred points or more
        cells, counts = np.unique(
            np.floor(scan.xyz[:, :2] / 2.0).astype(int), axis=0, return_counts=True
        )
        dense = {(a, b) for a, b in cells[counts >= 100].tolist()}
        assert dense <= columns(scan.xyz[rows]), dense - columns(scan.xyz[rows])
        # the counts in the legend stay those of every point
        assert data.counts["fused"].sum() == POINTS
    finally:
        page.close()
