"""The viewer's layout, links, keys and tools in Debian's headless chromium (issue 32).

Each test drives the page as a user does (clicks, the job picker, the address bar) and checks
what the browser shows against the scene the server sent: panel columns in a screenshot, the
nodes' positions and points, the answer of a click on a known point.
"""

from __future__ import annotations

import base64
import io
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import quote, unquote

import numpy as np
import pytest
from PIL import Image

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.io import read_scan
from tests.support.shots import (
    HIDE_OVERLAYS,
    VIEWPORT,
    WIDE_VIEWPORT,
    canvas_box,
    panel_spans,
    settled,
)
from tests.support.viewer_pages import free_port, key_in, open_tab, view_of, wait_for
from web.layout import panel_offsets
from web.overlay import layout
from web.scene import SEGMENTS
from web.sources import DirectorySource
from web.viewer import Viewer

KEY = "s3cret-key"


@pytest.fixture(scope="module")
def locked(jobs: Path) -> Iterator[Viewer]:
    """The same jobs behind a key, as the job service runs the viewer when it has API keys."""
    instance = Viewer(DirectorySource(jobs), port=free_port(), authorise=lambda k: k == KEY)
    try:
        yield instance
    finally:
        instance.stop()


def shown(page: Any) -> Any:
    status = page.get_by_text("points shown")
    status.wait_for(timeout=30_000)
    return status


def settled_view(browser: Any, viewer: Viewer, job_id: str) -> tuple[Any, Any]:
    """A new tab on ``job_id`` once its scene is drawn, and its server-side view."""
    page = open_tab(browser, viewer.link(job_id))
    shown(page)
    settled(page)
    return page, view_of(viewer, job_id)


def drawn_count(page: Any) -> int:
    found = re.search(r"\*?\*?[^:]*: ([\d,]+) of ([\d,]+) points shown", shown(page).inner_text())
    assert found is not None
    return int(found.group(1).replace(",", ""))


def field(page: Any, label: str) -> Any:
    """The text or number input of the viser control labelled ``label`` (viser labels its
    inputs with a text beside them, not a <label>)."""
    row = page.get_by_text(label, exact=True).locator(
        "xpath=ancestor::div[contains(@class, 'mantine-Flex-root')][1]"
    )
    return row.locator("input").first


def address(page: Any) -> str:
    """The page's address now (``page.url`` only changes when Playwright handles its events)."""
    return str(page.evaluate("location.href"))


# ------------------------------------------------------------------------------------- keys
def test_the_viewer_asks_for_the_key_and_shows_nothing_without_it(
    browser: Any, locked: Viewer, artifacts: Path
) -> None:
    # no key: a sign-in box, no job list, no points, no view on the server
    context = browser.new_context(viewport=VIEWPORT)
    page = context.new_page()
    try:
        page.goto(locked.link("room"))
        page.add_style_tag(content=HIDE_OVERLAYS)
        page.get_by_text("This viewer needs a key").wait_for(timeout=30_000)
        # the key is typed into a password field: never shown as typed (issue 44)
        box = field(page, "API key")
        wait_for(lambda: box.get_attribute("type") == "password", what="a password field")
        (artifacts / "viewer_sign_in.png").write_bytes(page.screenshot())
        assert page.get_by_label("Job", exact=True).count() == 0
        assert page.get_by_text("points shown").count() == 0
        assert page.get_by_text("room.ply").count() == 0
        assert not locked.views
        # a wrong key typed in is refused, still nothing shown
        box.fill("wrong")
        page.get_by_role("button", name="Sign in").click()
        page.get_by_text("This key was refused").wait_for(timeout=15_000)
        assert not locked.views and not locked.sessions
        # the right key opens the job of the link
        box.fill(KEY)
        # the field is drawn anew after a refusal; its script makes it a password field again
        # (a style hides the characters until then)
        wait_for(lambda: box.get_attribute("type") == "password", what="a password field")
        page.get_by_role("button", name="Sign in").click()
        shown(page)
        assert view_of(locked, "room").job_id == "room"
        # the key never goes into the address, in clear or encoded (a copied link does not
        # carry it); the browser keeps a session token of the viewer's, not the key
        wait_for(lambda: "job%2Froom" in address(page), what="the address")
        assert not key_in(address(page), KEY) and "k." not in address(page)
        (cookie,) = [c for c in context.cookies() if c["name"] == locked.cookie]
        assert not key_in(cookie["value"], KEY) and len(cookie["value"]) >= 32
        # signed in once: a reload (or another link in this browser) needs no key
        page.reload()
        shown(page)
        assert page.get_by_text("This viewer needs a key").count() == 0
        assert not key_in(address(page), KEY)
        # signing out ends the session: the tab asks for a key again
        page.get_by_role("button", name="Sign out").click()
        page.get_by_text("This viewer needs a key").wait_for(timeout=30_000)
        assert [c for c in context.cookies() if c["name"] == locked.cookie] == []
        assert not locked.sessions
    finally:
        context.close()
    # a key in a link (as links once carried it: ?key=, or a k. token) is never used
    port = locked.port
    b64 = base64.urlsafe_b64encode(KEY.encode()).decode().rstrip("=")
    for query in (f"?key={KEY}", f"?v=k.{b64}"):
        ws = f"ws://127.0.0.1:{port}/job/bare{query}"
        page = open_tab(browser, f"http://127.0.0.1:{port}/?websocket={quote(ws, safe='')}")
        try:
            page.get_by_text("the one in this link was not used").wait_for(timeout=30_000)
            time.sleep(0.5)
            assert page.get_by_text("points shown").count() == 0
            assert not [v for v in list(locked.views.values()) if v.job_id == "bare"]
        finally:
            page.close()


# ----------------------------------------------------------------------------- layout
def choose_job(page: Any, job_id: str) -> None:
    """Pick ``<job_id>.ply`` in the job picker and wait until its status line shows."""
    page.get_by_label("Job", exact=True).click()
    page.get_by_role("option", name=f"{job_id}.ply", exact=False).click()
    page.locator("strong", has_text=f"{job_id}.ply [{job_id}]").wait_for(timeout=30_000)


def even_spans(image: np.ndarray, count: int) -> None:
    """``count`` panels of about one width: none drawn over another."""
    spans = panel_spans(image, count)
    widths = [b - a for a, b in spans]
    assert min(widths) > 0.7 * max(widths), spans


def test_switching_jobs_lays_out_every_panel_without_overlap_and_the_url_follows(
    browser: Any, viewer: Viewer, artifacts: Path
) -> None:
    page = open_tab(browser, viewer.link("room"))
    try:
        shown(page)
        assert len(panel_spans(settled(page), 4)) == 4
        view = view_of(viewer, "room")
        # pick the job without ground truth in the picker: three panels, evenly laid out
        choose_job(page, "bare")
        image = settled(page)
        (artifacts / "viewer_switched_to_bare.png").write_bytes(page.screenshot())
        even_spans(image, 3)
        data = view.data
        assert data is not None and view.job_id == "bare"
        expected = panel_offsets(data.extent, 3)
        frames = [view.panels.frames[k] for k in ("raw", "network", "fused")]
        assert np.allclose([f.position for f in frames], expected)
        # nothing of the first job is left in the scene
        assert all(key[0] in ("raw", "network", "fused") for key in view.panels.nodes)
        # a scan without labels leaves the ground truth box unticked and disabled
        box = page.get_by_label("Ground truth panel", exact=True)
        assert not box.is_checked() and box.is_disabled()
        # the address names the job now: a reload shows it again
        wait_for(lambda: "job%2Fbare" in address(page), what="the address to follow the job")
        page.reload()
        page.add_style_tag(content=HIDE_OVERLAYS)
        page.locator("strong", has_text="bare.ply [bare]").wait_for(timeout=30_000)
        # and back to the job with ground truth: four panels again
        choose_job(page, "room")
        even_spans(settled(page), 4)
    finally:
        page.close()


def test_the_shown_points_line_follows_class_toggles_and_changed_only(
    browser: Any, viewer: Viewer, jobs: Path
) -> None:
    page = open_tab(browser, viewer.link("room"))
    try:
        shown(page)
        view = view_of(viewer, "room")
        data = view.data
        assert data is not None
        fused = data.fused
        everything = int((fused != 0).sum())  # the ceiling starts hidden
        wait_for(lambda: drawn_count(page) == everything, what="the first count")
        counts = np.bincount(fused[fused >= 0], minlength=NUM_CLASSES)
        counts[0] = 0
        off = int(np.argmax(counts))
        page.get_by_role("button", name=CLASS_NAMES[off], exact=True).click()
        wait_for(lambda: drawn_count(page) == everything - counts[off], what="class off")
        page.get_by_role("button", name=CLASS_NAMES[off], exact=True).click()
        page.get_by_label("Only points changed by fusion", exact=True).check()
        changed = int((data.changed & (fused != 0)).sum())
        wait_for(lambda: drawn_count(page) == changed, what="changed only")
        assert 0 < changed < everything
    finally:
        page.close()


def test_five_and_seven_panels_fit_the_view(browser: Any, viewer: Viewer, artifacts: Path) -> None:
    page = open_tab(browser, viewer.link("room"), viewport=WIDE_VIEWPORT)
    try:
        shown(page)
        width = int(canvas_box(page)["width"])
        for box, count in (("Segments panel", 5), ("Confidence panel", 6), ("Error map panel", 7)):
            page.get_by_label(box, exact=True).check()
            image = settled(page)
            (artifacts / f"viewer_{count}_panels.png").write_bytes(page.screenshot())
            spans = panel_spans(image, count)
            assert spans[0][0] > 8 and spans[-1][1] < width - 8, (count, spans)  # none clipped
    finally:
        page.close()


# ------------------------------------------------------------------------- click tools
def clear_point(
    data: Any,
    rows: np.ndarray,
    back: np.ndarray,
    clearance: float,
    candidates: np.ndarray | None = None,
) -> int:
    """A row of ``candidates`` (default: ``rows``) whose line of sight towards ``back`` passes
    no other drawn point (``rows``: every point drawn) closer than ``clearance`` (so a click on
    it hits it, not something in front), nor, just in front of it, a neighbour within a few
    centimetres of the line (a ray hits the first point within a point's size of it: on a
    tilted surface that may be the next point up the slope)."""
    xyz = data.xyz[rows].astype(np.float64)
    pool = rows if candidates is None else candidates
    for i in np.random.default_rng(0).permutation(pool)[:400]:
        rel = xyz - data.xyz[i]
        along = rel @ back
        off = np.linalg.norm(rel - along[:, None] * back, axis=1)
        blocked = ((along > 0.15) & (off < clearance)) | ((along > 0.005) & (off < 0.03))
        if not np.any(blocked):
            return int(i)
    raise AssertionError("no clear point")


def visible_rows(view: Any, panel: str) -> np.ndarray:
    return np.asarray(view.panels.drawn_rows(panel))


def aim(page: Any, view: Any, panel: str, row: int, back: np.ndarray) -> None:
    """Point the camera of ``view`` at ``row`` of ``panel`` from direction ``back``; wait until
    the browser reports it back (setting the pose changes the server's copy at once: a click
    sent before the browser applied it would go through the old pose)."""
    target = view.data.xyz[row].astype(np.float64) + np.asarray(view.panels.frames[panel].position)
    position = target + 2.5 * back
    view.camera.place(position, target)
    camera = view.client.camera
    wait_for(
        lambda: view.camera.reported(position, target),
        what=f"the camera {camera.position} {camera.look_at} != {position} {target}",
    )


def click_centre(page: Any) -> None:
    box = canvas_box(page)
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)


def answer(page: Any, pattern: str) -> re.Match[str]:
    found: list[re.Match[str]] = []

    def seen() -> bool:
        text = page.locator("body").inner_text()
        m = re.search(pattern, text)
        if m:
            found.append(m)
        return m is not None

    try:
        wait_for(seen, what=f"an answer matching {pattern!r}")
    except AssertionError as exc:  # say what the viewer told instead
        shown = page.locator("body").inner_text()
        told = [line for line in shown.splitlines() if ":" in line or line.startswith("Point x")]
        raise AssertionError(f"{exc}; the viewer told: {told[-12:]}") from None
    return found[0]


BACK = np.array([0.0, -0.35, 1.0]) / np.linalg.norm([0.0, -0.35, 1.0])


def test_a_click_tells_a_known_points_labels_object_and_room_and_two_clicks_measure_it(
    browser: Any, viewer: Viewer, jobs: Path, artifacts: Path
) -> None:
    page, view = settled_view(browser, viewer, "room")
    try:
        data = view.data
        rows = visible_rows(view, "fused")
        first = clear_point(data, rows, BACK, 0.25)
        aim(page, view, "fused", first, BACK)
        click_centre(page)
        m = answer(page, r"Point x (-?[\d.]+), y (-?[\d.]+), z (-?[\d.]+)")
        scan = read_scan(jobs / "room.ply")
        picked = np.array([float(v) for v in m.groups()])
        nearest = int(np.argmin(np.linalg.norm(scan.xyz - picked, axis=1)))
        assert np.linalg.norm(scan.xyz[nearest] - (data.xyz[first] + data.centre)) < 1e-3
        body = page.locator("body").inner_text()
        fused_name = CLASS_NAMES[int(scan.fields["fused_label"][nearest])]
        net_name = CLASS_NAMES[int(scan.fields["network_label"][nearest])]
        assert scan.labels is not None
        truth_name = CLASS_NAMES[int(scan.labels[nearest])]
        assert f"fused: {fused_name}" in body and f"network: {net_name}" in body
        assert f"ground truth: {truth_name}" in body
        assert f"segment: {int(scan.fields['segment'][nearest])}" in body
        conf = float(scan.fields["network_confidence"][nearest])
        assert f"confidence {conf:.2f}" in body
        (artifacts / "viewer_pick.png").write_bytes(page.screenshot())

        # measure: two clicks on two known points give their distance within 1 mm
        page.get_by_label("Click to", exact=True).click()
        page.get_by_role("option", name="Measure distance").click()
        page.get_by_text("Click two points.").wait_for(timeout=10_000)
        second, pool = None, rows
        for _ in range(20):  # a clear point a metre or more away (every drawn point may hide it)
            candidate = clear_point(data, rows, BACK, 0.25, candidates=pool)
            if np.linalg.norm(data.xyz[candidate] - data.xyz[first]) > 1.0:
                second = candidate
                break
            pool = pool[pool != candidate]
        assert second is not None
        aim(page, view, "fused", first, BACK)
        click_centre(page)
        page.get_by_text("Distance: click a second point.").wait_for(timeout=10_000)
        aim(page, view, "fused", second, BACK)
        click_centre(page)
        m = answer(page, r"Distance ([\d.]+) m")
        truth = float(np.linalg.norm(data.xyz[second].astype(np.float64) - data.xyz[first]))
        assert abs(float(m.group(1)) - truth) <= 1e-3, (m.group(1), truth)
        (artifacts / "viewer_measure.png").write_bytes(page.screenshot())
        check_objects(page, view, jobs, artifacts)
    finally:
        page.close()


# ------------------------------------------------------------------ links and downloads
def test_a_link_with_the_view_state_reproduces_camera_and_toggles(
    browser: Any, viewer: Viewer
) -> None:
    page = open_tab(browser, viewer.link("room"))
    other = None
    try:
        shown(page)
        view = view_of(viewer, "room")
        page.get_by_role("button", name="wall", exact=True).click()
        page.get_by_label("Segments panel", exact=True).check()
        page.get_by_role("button", name="Top").click()
        # the plan, once the browser draws it (a report sent before it still holds the overview)
        wait_for(lambda: view.camera.ortho and view.camera.applied(), what="the preset view")
        before = np.asarray(view.client.camera.position)
        pose = ",".join(f"{v:.4f}" for v in before)
        wait_for(lambda: pose in unquote(address(page)) and "p." in address(page), what="address")
        link = address(page)
        other = open_tab(browser, link)
        shown(other)
        copy = view_of(viewer, "room", exclude=(view,))
        try:
            wait_for(lambda: np.allclose(copy.client.camera.position, before, atol=2e-3))
        except AssertionError:  # say where it went instead
            camera = copy.client.camera
            raise AssertionError(
                f"the linked camera is at {camera.position}, looks at {camera.look_at} "
                f"(field {camera.fov:.4f} rad), not at {before}; link {link}"
            ) from None
        assert np.allclose(copy.client.camera.look_at, view.client.camera.look_at, atol=2e-3)
        assert copy.hidden == view.hidden and 2 in copy.hidden
        assert copy.ui.panel_boxes[SEGMENTS].value and not copy.class_shown(2)
        assert len(panel_spans(settled(other), 5)) == 5
    finally:
        page.close()
        if other is not None:
            other.close()


def test_the_screenshot_button_downloads_a_png_and_the_point_budget_caps_the_points_sent(
    browser: Any, viewer: Viewer
) -> None:
    page, view = settled_view(browser, viewer, "room")
    try:
        page.get_by_label("Screenshot size", exact=True).click()
        page.get_by_role("option", name="1x canvas").click()
        with page.expect_download(timeout=60_000) as info:
            page.get_by_role("button", name="Screenshot (PNG)").click()
        assert info.value.suggested_filename == "room_view.png"
        blob = Path(info.value.path()).read_bytes()
        assert blob[:8] == b"\x89PNG\r\n\x1a\n"
        image = np.asarray(Image.open(io.BytesIO(blob)).convert("RGB")).copy()
        box = canvas_box(page)
        assert abs(image.shape[1] - box["width"]) <= 2 and abs(image.shape[0] - box["height"]) <= 2
        legend = layout(view.overlay_state(1), image.shape[0])["box"]
        image[legend[1] :, : legend[2] + 2] = image[2, 2]  # the legend's corner, blanked
        assert len(panel_spans(image, 4)) == 4  # the panels, as on the screen

        data = view.data
        assert data is not None and data.xyz.shape[0] > 20_000
        budget = field(page, "Point budget")
        budget.fill("5000")
        budget.press("Enter")
        # the status line names the budget once every panel is sent again
        page.get_by_text(re.compile(r"budget 5,000 of")).wait_for(timeout=30_000)
        for panel in ("raw", "network", "fused", "truth"):
            sent = sum(
                n.points.shape[0] for k, n in list(view.panels.nodes.items()) if k[0] == panel
            )
            assert sent == 5000, (panel, sent)
        assert len(panel_spans(settled(page, min_ink=2000), 4)) == 4
    finally:
        page.close()


def well_inside_a_room(xyz: np.ndarray, rooms: list[dict], margin: float = 0.25) -> np.ndarray:
    """Points whose plan position lies inside a room's footprint, as do the four points
    ``margin`` away along x and y (matplotlib's test, not the viewer's)."""
    from matplotlib.path import Path as Outline

    out = np.zeros(len(xyz), dtype=bool)
    for room in rooms:
        outline = Outline(np.asarray(room["footprint"], dtype=np.float64))
        ok = np.ones(len(xyz), dtype=bool)
        for dx, dy in ((0, 0), (margin, 0), (-margin, 0), (0, margin), (0, -margin)):
            ok &= outline.contains_points(xyz[:, :2] + (dx, dy))
        out |= ok
    return out


def check_objects(page: Any, view: Any, jobs: Path, artifacts: Path) -> None:
    """Objects and rooms: boxes drawn, listed by class, told on a click (issue 33)."""
    import json

    report = json.loads((jobs / "room.report.json").read_text())
    objects, rooms = report["objects"], report["rooms"]["rooms"]
    assert objects and rooms
    data = view.data
    # every object's box: 12 edges each, in the fused panel, one node per class
    assert view.panels.boxes is not None
    assert sum(node.points.shape[0] for node in view.panels.boxes.values()) == 12 * len(objects)
    assert {CLASS_NAMES[c] for c in view.panels.boxes} == {o["cls"] for o in objects}
    body = page.locator("body").inner_text()
    assert "Objects and rooms" in body and rooms[0]["name"] in body
    # the list counts whole objects by class; fragments (not plausible as their class) apart
    chairs = sum(o["cls"] == "chair" and o.get("plausible", True) for o in objects)
    assert chairs == 0 or re.search(rf"chair\s+{chairs}\b", body)
    # a click on a point of an object tells the object and the room
    page.get_by_label("Click to", exact=True).click()
    page.get_by_role("option", name="Pick a point").click()
    rows = visible_rows(view, "fused")
    # an object's point inside a room, 25 cm or more from its outline (a clutter object on
    # the wall is outside the room), that no drawn point hides (a wall in front of a board
    # on it does)
    inner = well_inside_a_room(data.xyz[rows] + data.centre, rooms)
    target = clear_point(
        data, rows, BACK, 0.25, candidates=rows[(data.instance[rows] >= 0) & inner]
    )
    aim(page, view, "fused", target, BACK)
    click_centre(page)
    m = answer(page, r"object: (\w+) (\d+)")
    assert int(m.group(2)) == int(data.instance[target])
    record = next(o for o in objects if o["id"] == int(data.instance[target]))
    assert m.group(1) == record["cls"]
    answer(page, r"room: Room \d+")
    (artifacts / "viewer_objects.png").write_bytes(page.screenshot())
    # the boxes can be switched off
    page.get_by_label("Object boxes", exact=True).uncheck()
    wait_for(lambda: not any(n.visible for n in view.panels.boxes.values()), what="boxes hidden")


# ------------------------------------------------------------------------ object boxes
def changed_pixels(a: np.ndarray, b: np.ndarray, span: tuple[int, int]) -> int:
    """Pixels that differ between two grabs inside one panel's columns."""
    return int(np.count_nonzero((a[:, span[0] : span[1]] != b[:, span[0] : span[1]]).any(-1)))


def test_object_boxes_follow_the_class_buttons_and_their_switch_is_in_the_link(
    browser: Any, viewer: Viewer, jobs: Path, artifacts: Path
) -> None:
    """Issue 45, point 4: hiding a class hides its objects' boxes with its points, and *Object
    boxes* off is kept in the address, so the link opens with them off.

    The boxes are told apart on the screen by switching them: with every class that has boxes
    hidden, *Object boxes* on or off must draw the same pixels (no edge is left over)."""
    page, view = settled_view(browser, viewer, "room")
    other = None
    try:
        assert view.panels.boxes is not None and len(view.panels.boxes) >= 2
        boxes = page.get_by_label("Object boxes", exact=True)
        on = settled(page)
        fused = panel_spans(on, 4)[2]
        boxes.uncheck()
        assert changed_pixels(on, settled(page), fused) > 200  # the edges show on the screen
        boxes.check()
        shown_classes = [c for c in view.panels.boxes if view.class_shown(c)]
        first = shown_classes[0]
        page.get_by_role("button", name=CLASS_NAMES[first], exact=True).click()
        wait_for(lambda: not view.panels.boxes[first].visible, what="the class's boxes hidden")
        assert all(n.visible for c, n in view.panels.boxes.items() if c != first)  # the others stay
        for cls in shown_classes[1:]:
            page.get_by_role("button", name=CLASS_NAMES[cls], exact=True).click()
        wait_for(lambda: not any(n.visible for n in view.panels.boxes.values()), what="all hidden")
        hidden = settled(page, min_ink=5000)
        (artifacts / "viewer_boxes_classes_hidden.png").write_bytes(page.screenshot())
        boxes.uncheck()
        assert changed_pixels(hidden, settled(page, min_ink=5000), fused) <= 10
        boxes.check()
        for cls in shown_classes:
            page.get_by_role("button", name=CLASS_NAMES[cls], exact=True).click()
        wait_for(
            lambda: all(view.panels.boxes[c].visible for c in shown_classes), what="boxes back"
        )

        # boxes off: the address says so, and a link opens with them off
        assert "x.0" not in address(page)
        boxes.uncheck()
        wait_for(lambda: "x.0" in address(page), what="boxes off in the address")
        other = open_tab(browser, address(page))
        shown(other)
        copy = view_of(viewer, "room", exclude=(view,))
        assert not other.get_by_label("Object boxes", exact=True).is_checked()
        assert copy.panels.boxes is not None and copy.panels.boxes
        assert not any(n.visible for n in copy.panels.boxes.values())
        # and on again: the token leaves the address
        other.get_by_label("Object boxes", exact=True).check()
        wait_for(lambda: "x.0" not in address(other), what="boxes on in the address")
        assert all(n.visible for c, n in copy.panels.boxes.items() if copy.class_shown(c))
    finally:
        page.close()
        if other is not None:
            other.close()
