"""The viewer's *Frame* folder (web.frame_panel): the frame stage's decision, and its re-run
handed to the job page (the viewer holds no API key)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import pytest

from tests.support.viewer_pages import free_port, open_tab, view_of, wait_for
from web.frame_panel import decision_markdown, flipped
from web.sources import DirectorySource
from web.viewer import Viewer

UNSURE = {
    "up": {"axis": "+y", "tilt_degrees": 3.21, "levelled": True, "confidence": 0.41},
    "units": {"unit": "mm", "confidence": 0.93},
    "warnings": ["up axis unsure (+y, confidence 0.41): check the labels, or set it with --up"],
}


def test_flip_is_the_other_side_of_the_same_axis() -> None:
    assert [flipped(a) for a in ("+z", "-z", "+y", "-x")] == ["-z", "+z", "-y", "+x"]


def test_the_decision_names_axis_tilt_units_with_confidence_and_flags_the_unsure_one() -> None:
    text = decision_markdown(UNSURE)
    up, tilt, units, warning = text.splitlines()
    assert "+y" in up and "0.41" in up and "unsure" in up
    assert "3.2°" in tilt and "levelled" in tilt
    assert "mm" in units and "0.93" in units and "unsure" not in units
    assert "unsure" in warning and "up axis unsure" in warning


class ServiceLikeSource(DirectorySource):
    """A folder of results with a job page at ``job_page_port`` (as the service's source)."""

    job_page_port: int | None = None


@pytest.fixture(scope="module")
def framed(jobs: Path) -> Iterator[Viewer]:
    source = ServiceLikeSource(jobs)
    source.job_page_port = free_port()
    instance = Viewer(source, port=free_port())
    try:
        yield instance
    finally:
        instance.stop()


def test_the_frame_folder_shows_the_decision_and_opens_the_job_page_on_a_flip(
    browser: Any, framed: Viewer, jobs: Path
) -> None:
    frame = json.loads((jobs / "room.report.json").read_text())["frame"]
    axis = frame["up"]["axis"]
    port = framed.source.job_page_port  # type: ignore[attr-defined]
    page = open_tab(browser, framed.link("room"))
    try:
        page.get_by_text("points shown").wait_for(timeout=30_000)
        view = view_of(framed, "room")
        page.get_by_text("Frame", exact=True).click()  # the folder opens
        page.get_by_text(f"confidence {frame['up']['confidence']:.2f}").first.wait_for(
            timeout=10_000
        )
        assert view.frame.up.value == axis and view.frame.units.value == frame["units"]["unit"]
        page.get_by_role("button", name="Flip up").click()
        wait_for(lambda: view.frame.up.value == flipped(axis), what="the flip")
        # the job page (a stand-in here) opens in a new tab on this job's frame box
        page.context.route(
            f"http://127.0.0.1:{port}/**",
            lambda route: route.fulfill(status=200, content_type="text/html", body="job page"),
        )
        with page.context.expect_page(timeout=15_000) as info:
            page.get_by_role("button", name="Re-run with this frame").click()
        opened = info.value
        try:
            wait_for(lambda: "#frame=" in opened.url, what="the job page's address")
            address = urlsplit(opened.url)
            assert address.port == port
            wanted = parse_qs(address.fragment)
            assert wanted == {
                "frame": ["room"],
                "up": [flipped(axis)],
                "units": [frame["units"]["unit"]],
            }
        finally:
            opened.close()
    finally:
        page.close()
