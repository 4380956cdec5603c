"""The views a surveyor expects, in Debian's headless chromium (issue 45, point 4).

The plan and the elevations as near-orthographic views centred on the room (a stray point far
away left out of every fit), a slice and a clip box that hide points in every panel, the legend
and scale bar over the canvas, and a screenshot at twice the canvas with both drawn in. The
camera is read as the browser reports it (viser's ``client.camera`` once it matches what the
viewer set), so a pose the browser never applied does not pass.
"""

from __future__ import annotations

import io
import logging
import math
import re
import shutil
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np
import pytest
from PIL import Image

from jointseg.io import read_scan, write_scan
from tests.support.camera_math import corners, project
from tests.support.result_files import with_stray_point
from tests.support.shots import (
    canvas_box,
    ink,
    palette_pixels,
    panel_spans,
    settled,
)
from tests.support.viewer_pages import free_port, open_tab, view_of, wait_for
from web.layout import ORTHO_SCALE_ERROR, title_position
from web.object_list import SELECTED_COLOUR
from web.overlay import layout
from web.sources import DirectorySource
from web.viewer import Viewer

log = logging.getLogger(__name__)
FLOOR, WALL = 1, 2


@pytest.fixture(scope="module")
def views(jobs: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Viewer]:
    """A viewer on ``room`` and ``stray``: the same room with one point 100 m away."""
    folder = tmp_path_factory.mktemp("views")
    for name in ("room.ply", "room.report.json"):
        shutil.copy(jobs / name, folder / name)
    write_scan(
        with_stray_point(read_scan(jobs / "room.ply"), (100.0, 0.0, 0.0)), folder / "stray.ply"
    )
    instance = Viewer(DirectorySource(folder), port=free_port())
    try:
        yield instance
    finally:
        instance.stop()


@contextmanager
def opened(
    browser: Any, viewer: Viewer, job_id: str, *, overlay: bool = False
) -> Iterator[tuple[Any, Any]]:
    """A new tab on ``job_id`` once its scene is drawn, and its server-side view; closed after."""
    page = open_tab(browser, viewer.link(job_id))
    try:
        if overlay:  # show the legend again (the toasts stay hidden)
            page.add_style_tag(content="#jointseg-overlay { display: block !important; }")
        page.get_by_text("points shown").wait_for(timeout=30_000)
        settled(page)
        yield page, view_of(viewer, job_id)
    finally:
        page.close()


def browser_camera(view: Any) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Position, look-at, field of view and aspect of the camera once the browser reports the
    pose the viewer set."""
    camera = view.client.camera
    wait_for(view.camera.applied, what="the browser to apply the viewer's camera")
    width, height = view.camera.canvas()
    return np.array(camera.position), np.array(camera.look_at), float(camera.fov), width / height


def seen_panels(view: Any) -> list[tuple[str, np.ndarray, Callable[[np.ndarray], Any]]]:
    """Each visible panel's key and offset, and where a point falls in the browser's view
    (normalised image coordinates)."""
    position, look_at, fov, aspect = browser_camera(view)

    def seen(point: np.ndarray) -> tuple[float, float]:
        return project(point, position, look_at, fov, aspect)

    frames = view.panels.frames
    return [(p.key, np.asarray(frames[p.key].position), seen) for p in view.visible_panels()]


def in_view(view: Any, low: np.ndarray, high: np.ndarray) -> float:
    """How far out the box (``low``..``high`` in every visible panel) reaches in the view (the
    largest normalised image coordinate); asserts every corner is inside."""
    reach = 0.0
    for key, offset, seen in seen_panels(view):
        for corner in corners(low + offset, high + offset):
            u, v = seen(corner)
            assert abs(u) < 1 and abs(v) < 1, (key, corner, u, v)
            reach = max(reach, abs(u), abs(v))
    return reach


def test_the_plan_looks_straight_down_holds_the_room_and_stays_a_plan_when_zoomed(
    browser: Any, views: Viewer, artifacts: Path
) -> None:
    with opened(browser, views, "room") as (page, view):
        page.get_by_role("button", name="Top").click()
        wait_for(lambda: view.camera.ortho, what="the plan")
        position, look_at, fov, _ = browser_camera(view)
        down = (look_at - position) / np.linalg.norm(look_at - position)
        assert math.degrees(math.acos(float(down @ [0.0, 0.0, -1.0]))) < 1.0
        half = view.data.extent / 2
        assert in_view(view, -half, half) > 0.8  # the room's box, every panel, filling the view
        # as good as orthographic: the room's depth changes the scale by at most 2 %
        offset = np.asarray(view.panels.frames["fused"].position)
        depths = (corners(offset - half, offset + half) - position) @ down
        assert depths.max() / depths.min() - 1.0 <= ORTHO_SCALE_ERROR + 1e-6
        assert len(panel_spans(settled(page), 4)) == 4
        (artifacts / "viewer_plan.png").write_bytes(page.screenshot())
        # a wheel zoom: still a plan, from as far, through a narrower field
        distance = float(np.linalg.norm(position - look_at))
        box = canvas_box(page)
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        for _ in range(3):
            page.mouse.wheel(0, -300)
            time.sleep(0.2)

        def zoomed() -> bool:
            now = view.client.camera
            far = float(np.linalg.norm(now.position - now.look_at))
            return abs(far - distance) < 0.01 * distance and now.fov < 0.9 * fov

        wait_for(zoomed, what="a zoom kept a plan")
        position, look_at, _, _ = browser_camera(view)
        down = (look_at - position) / np.linalg.norm(look_at - position)
        assert math.degrees(math.acos(float(down @ [0.0, 0.0, -1.0]))) < 1.0
        # an orbit that tilts the plan: a perspective view again, with the usual field (a turn
        # about the vertical leaves a plan, turned)
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.down()
        page.mouse.move(
            box["x"] + box["width"] / 2 + 40, box["y"] + box["height"] / 2 - 150, steps=10
        )
        page.mouse.up()
        wait_for(lambda: not view.camera.ortho, what="the orbit to end the plan")
        wait_for(
            lambda: abs(math.degrees(view.client.camera.fov) - 50.0) < 0.5,  # as reported
            what="a perspective view's field",
        )


def test_fit_and_the_plan_frame_the_room_with_a_stray_point_100_m_away(
    browser: Any, views: Viewer, jobs: Path, artifacts: Path
) -> None:
    with opened(browser, views, "stray") as (page, view):
        data = view.data
        assert np.abs(data.xyz).max() > 95  # the stray point is drawn, far out of the fit
        room = read_scan(jobs / "room.ply").xyz - data.centre
        low, high = room.min(axis=0), room.max(axis=0)
        # Fit all, asked for: the overview the tab opened with may have been left already on a
        # loaded machine (a camera report from before the browser applied it, over 10 s late)
        page.get_by_role("button", name="Fit all").click()
        wait_for(lambda: view.camera.auto and view.camera.applied(), what="the overview")
        assert in_view(view, low, high) > 0.5  # every panel's room, filling the view
        (artifacts / "viewer_stray_fit.png").write_bytes(page.screenshot())
        page.get_by_role("button", name="Top").click()
        wait_for(lambda: view.camera.ortho, what="the plan")
        assert in_view(view, low, high) > 0.7
        assert len(panel_spans(settled(page), 4)) == 4


def label_pixels(image: np.ndarray) -> list[np.ndarray]:
    """Palette pixels of the network, fused and ground truth panels of a four-panel row."""
    spans = panel_spans(image, 4)
    return [palette_pixels(image, spans[i]) for i in (1, 2, 3)]


def sent_points(view: Any, panel: str) -> np.ndarray:
    return np.concatenate([n.points for k, n in view.panels.nodes.items() if k[0] == panel])


def switch(page: Any, view: Any, label: str) -> None:
    """Open the *Clip and slice* folder if needed and tick ``label``."""
    box = page.get_by_label(label, exact=True)
    if not box.is_visible():
        page.get_by_text("Clip and slice", exact=True).click()
    box.check()
    page.get_by_text("clipped to").wait_for(timeout=20_000)  # once every panel is sent again


def test_a_slice_hides_the_points_outside_its_heights_in_every_panel(
    browser: Any, views: Viewer, artifacts: Path
) -> None:
    with opened(browser, views, "room") as (page, view):
        before = label_pixels(settled(page))
        assert all(seen[FLOOR] > 100 and seen[WALL] > 100 for seen in before)
        view.ui.clip.heights.value = (1.0, 1.3)  # a plan cut (the slider, set as a drag would)
        switch(page, view, "Slice")
        floor = view.ui.clip.frame.floor
        data = view.data
        inside = (data.xyz[:, 2] >= floor + 1.0) & (data.xyz[:, 2] <= floor + 1.3)
        for panel in view.visible_panels():
            z = sent_points(view, panel.key)[:, 2]
            assert z.min() >= floor + 1.0 - 1e-4 and z.max() <= floor + 1.3 + 1e-4, panel.key
            assert z.size == int(inside.sum()), panel.key
        after = label_pixels(settled(page, min_ink=2000))
        (artifacts / "viewer_slice.png").write_bytes(page.screenshot())
        for seen in after:  # the floor is gone from every label panel, the walls stay
            assert seen[FLOOR] == 0 and seen[WALL] > 50, seen.tolist()
        # and the link keeps it
        wait_for(
            lambda: "s.1.000,1.300" in unquote(page.evaluate("location.href")), what="the link"
        )


def beyond(view: Any, image: np.ndarray, spans: list[tuple[int, int]], x: float) -> list[int]:
    """Drawn pixels of each panel of a plan right of ``x`` (scene coordinates, 6 pixels of
    margin for the points' size), below the panel's title."""
    height, width = image.shape[:2]
    drawn, half, counts = ink(image), view.data.extent / 2, []
    for (_, offset, seen), (_, end) in zip(seen_panels(view), spans, strict=True):
        # the edge's plane, at every height and depth (a near-orthographic view still leans)
        edge = corners(offset + [x, -half[1], -half[2]], offset + [x, half[1], half[2]])
        u = max(seen(c)[0] for c in edge)
        v = seen(offset + title_position(view.data.extent))[1]
        column, row = int((u + 1) / 2 * width) + 6, int((1 - v) / 2 * height) + 4
        counts.append(int(drawn[row:, column:end].sum()))
    return counts


def test_the_clip_box_keeps_its_points_in_every_panel(
    browser: Any, views: Viewer, artifacts: Path
) -> None:
    with opened(browser, views, "room") as (page, view):
        page.get_by_label("Object boxes", exact=True).uncheck()  # the points alone
        page.get_by_role("button", name="Top").click()
        wait_for(lambda: view.camera.ortho, what="the plan")
        before = settled(page)
        spans = panel_spans(before, 4)
        clip = view.ui.clip
        x0 = float(clip.frame.corner[0])
        clip.box[0].value = (0.0, round(0.4 * float(clip.frame.reach[0]) / 0.05) * 0.05)
        edge = x0 + clip.box[0].value[1]
        assert min(beyond(view, before, spans, edge)) > 500  # the room goes on past the edge
        switch(page, view, "Clip box")
        for panel in view.visible_panels():
            x = sent_points(view, panel.key)[:, 0]
            assert x.min() >= x0 - 1e-4 and x.max() <= edge + 1e-4, panel.key
        after = settled(page, min_ink=2000)
        (artifacts / "viewer_clip_box.png").write_bytes(page.screenshot())
        assert max(beyond(view, after, spans, edge)) <= 5  # nothing drawn past it, any panel


def test_a_screenshot_at_twice_the_canvas_holds_the_legend_and_the_scale_bar(
    browser: Any, views: Viewer, artifacts: Path
) -> None:
    with opened(browser, views, "room", overlay=True) as (page, view):
        page.get_by_role("button", name="Top").click()
        wait_for(lambda: view.camera.ortho, what="the plan")
        browser_camera(view)
        # the legend over the canvas names the classes drawn, and follows the class buttons
        legend = page.locator("#jointseg-overlay")
        bar = legend.locator(".jointseg-scale")
        wait_for(lambda: bar.count() == 1, what="the scale bar over the canvas")
        assert re.fullmatch(r"\d+ (m|cm)", bar.inner_text()), bar.inner_text()

        # the bar is its length on the canvas: its share of the canvas's height, on the page
        # (read again while a camera report redraws the overlay and detaches the bar)
        def bar_error() -> float:
            box = legend.locator(".jointseg-bar").bounding_box(timeout=5_000)
            state = view.overlay_state().bar
            if box is None or state is None:
                return float("inf")
            return abs(box["width"] - state.share * canvas_box(page)["height"])

        try:
            wait_for(lambda: bar_error() < 2, what="the bar at its share of the canvas")
        except AssertionError:
            raise AssertionError(f"the bar is {bar_error():.1f} px off its share") from None
        assert "wall" in legend.inner_text() and "ceiling" not in legend.inner_text()
        page.get_by_role("button", name="wall", exact=True).click()
        wait_for(lambda: "wall" not in legend.inner_text(), what="wall off the legend")
        page.get_by_role("button", name="wall", exact=True).click()
        wait_for(lambda: "wall" in legend.inner_text(), what="wall back on the legend")
        page.get_by_label("Screenshot size", exact=True).click()
        page.get_by_role("option", name="2x canvas").click()
        started = time.perf_counter()
        with page.expect_download(timeout=60_000) as info:
            page.get_by_role("button", name="Screenshot (PNG)").click()
        blob = Path(info.value.path()).read_bytes()
        log.info("screenshot: %.2f s from the click to the file", time.perf_counter() - started)
        image = np.asarray(Image.open(io.BytesIO(blob)).convert("RGB"))
        (artifacts / "viewer_screenshot_2x.png").write_bytes(blob)
        width, height = view.camera.canvas()
        assert image.shape[:2] == (2 * height, 2 * width)
        overlay = view.overlay_state(2)
        parts = layout(overlay, image.shape[0], 2.0)
        assert overlay.bar is not None and len(overlay.entries) >= 5
        for i, (_, rgb) in enumerate(overlay.entries):  # each swatch in its class's colour
            x0, y0, x1, y1 = parts[f"swatch{i}"]
            assert np.all(image[y0 + 1 : y1 - 1, x0 + 1 : x1 - 1] == rgb), i
        x0, y0, x1, y1 = parts["bar"]
        assert np.all(image[y0 + 1 : y1 - 1, x0 + 1 : x1 - 1] == (34, 34, 34))
        # and the panels, as on the screen
        box = parts["box"]
        image = image.copy()
        image[box[1] :, : box[2] + 2] = image[2, 2]
        assert len(panel_spans(image, 4)) == 4


def selected_pixels(image: np.ndarray, span: tuple[int, int]) -> int:
    """Pixels of a panel in (nearly) the selected object's orange (lines are drawn through a
    colour transform points are not: (255, 120, 0) shows as (241, 143, 31))."""
    part = image[:, span[0] : span[1]].astype(np.int16)
    return int((np.abs(part - np.array(SELECTED_COLOUR)).max(axis=2) <= 45).sum())


def test_a_click_in_the_object_list_flies_to_the_object_and_selects_it_in_every_panel(
    browser: Any, views: Viewer, artifacts: Path
) -> None:
    with opened(browser, views, "room") as (page, view):
        listed = view.objects.objects
        report = view.data.report["objects"]
        assert len(listed) == sum(o.get("plausible", True) for o in report) > 3
        # the list: every object with its class, size and height above the floor
        for obj in listed:
            record = next(o for o in report if o["id"] == obj.id)
            w, d, h = record["size"]
            text = f"{record['cls']} {obj.id} · {w:.2f}×{d:.2f}×{h:.2f} m"
            assert page.get_by_role("button", name=re.compile("^" + re.escape(text))).count() == 1
        before = settled(page)
        assert all(selected_pixels(before, s) == 0 for s in panel_spans(before, 4))
        target = max(listed, key=lambda o: o.radius)  # the biggest: seen in every panel
        page.get_by_role("button", name=target.label, exact=True).click()
        # the camera flies to the fused panel's copy, near enough to fill a good part of it
        fused = np.asarray(view.panels.frames["fused"].position)
        wait_for(
            lambda: np.allclose(view.client.camera.look_at, target.centre + fused, atol=1e-3),
            what="the flight to the object",
        )
        half = (target.corners.max(axis=0) - target.corners.min(axis=0)) / 2
        position, look_at, fov, aspect = browser_camera(view)
        reach = max(
            max(abs(u), abs(v))
            for u, v in (project(c, position, look_at, fov, aspect) for c in corners(
                target.centre + fused - half, target.centre + fused + half
            ))
        )  # fmt: skip
        assert 0.15 < reach < 1.0
        page.get_by_text(f"Selected: {target.name}").wait_for(timeout=10_000)
        # selected in every panel: its box around each copy, and on the screen
        for panel in view.visible_panels():
            assert np.allclose(view.panels.highlights[panel.key].points, target.edges())
        page.get_by_role("button", name="Fit all").click()
        wait_for(view.camera.applied, what="the overview")
        image = settled(page)
        (artifacts / "viewer_object_selected.png").write_bytes(page.screenshot())
        assert all(selected_pixels(image, s) > 10 for s in panel_spans(image, 4))


def test_the_screenshot_with_a_selection_downloads_a_png_with_the_box_drawn(
    browser: Any, views: Viewer, artifacts: Path
) -> None:
    """Issue 63: with an object selected in the object list, *Screenshot* sent nothing (the
    selected box's one colour broke the drawing of its edges)."""
    with opened(browser, views, "room") as (page, view):
        target = max(view.objects.objects, key=lambda o: o.radius)
        page.get_by_role("button", name=target.label, exact=True).click()
        page.get_by_text(f"Selected: {target.name}").wait_for(timeout=10_000)
        page.get_by_role("button", name="Fit all").click()
        wait_for(view.camera.applied, what="the overview")
        with page.expect_download(timeout=60_000) as info:
            page.get_by_role("button", name="Screenshot (PNG)").click()
        blob = Path(info.value.path()).read_bytes()
        (artifacts / "viewer_screenshot_selected.png").write_bytes(blob)
        image = np.asarray(Image.open(io.BytesIO(blob)).convert("RGB"))
        width, height = view.camera.canvas()
        assert image.shape[:2] == (2 * height, 2 * width)  # the default size: 2x the canvas
        orange = np.abs(image.astype(np.int16) - np.array(SELECTED_COLOUR)).max(axis=2) == 0
        assert orange.sum() > 40  # the selected box, drawn in
