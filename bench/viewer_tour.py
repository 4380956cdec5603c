"""The documentation's pictures, made from today's product, and what the point budget does for a
weak client's frame rate; in Debian's headless chromium.

The job page and the viewer as a user meets them (``docs/job_page.png``, ``docs/viewer.png``,
``docs/images/job_page_downloads.png``): ``jointseg serve`` with an API key, a real S3DIS room
uploaded on the job page and segmented by the service, its view link opened and signed in.

The viewer's tools on real scans (``docs/images/viewer_*.png``): the scans go through ``jointseg
segment`` with defaults (cached in --cache), an S3DIS Area_6 room (ground truth: error map and
confusion table) and a ScanNet scan, served behind an API key. The tour signs in, shows every
panel, picks a point, measures a distance, switches to one large panel with the error map in the
plan, shows the objects' boxes and the rooms, the plan with its legend and scale bar, a slice,
an object chosen in the object list, and times a screenshot at twice the canvas.

The IFC model of a synthetic 3-room floor through IfcOpenShell (``docs/images/ifc_floor.png``,
``bench/ifc_view.py``).

Then the record beside the pictures (``docs/images/pictures.json``, :mod:`web.pictures`): the
digest of the viewer's code they show; ``tests/docs/test_pictures.py`` fails once that code
changes, until the tour is run again.

Frame rate: a 300 000-point synthetic result (the pipeline's fields filled, as bench/viewer.py
does for big results) with five panels, orbited by the server moving the camera every 50 ms
while the page counts animation frames for --seconds; once with every point sent, then with
lower point budgets. SwiftShader (chromium's software WebGL) stands in for a weak client.

    .venv/bin/python bench/viewer_tour.py [--cache bench/_cache] [--no-fps]
        [--budgets 300000,100000,30000] [--seconds 6]
"""

from __future__ import annotations

import argparse
import math
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from helpers.report import header

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
SHARED = ROOT.parent / "shared" / "data"
JOINTSEG = str(Path(sys.executable).parent / "jointseg")
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--no-first-run", "--disable-dev-shm-usage"]  # fmt: skip
KEY = "tour-key"
HIDE_TOASTS = '[class*="mantine-Notifications"] { display: none !important; }'
SCANS = {
    "area6_office_4": SHARED / "s3dis_area6" / "area6_office_4.ply",
    "scene0002_00": SHARED / "scannet" / "scene0002_00.ply",
}


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def segmented(folder: Path, cache: Path) -> None:
    """Each real scan segmented with defaults into ``folder`` (results cached in ``cache``)."""
    cache.mkdir(parents=True, exist_ok=True)
    for name, source in SCANS.items():
        out, report = cache / f"tour_{name}.ply", cache / f"tour_{name}.report.json"
        if not out.exists():
            subprocess.run(
                [JOINTSEG, "segment", str(source), "-o", str(out), "--report", str(report)],
                check=True,
                capture_output=True,
            )
        (folder / f"{name}.ply").write_bytes(out.read_bytes())
        (folder / f"{name}.report.json").write_bytes(report.read_bytes())


def wait(condition: Any, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.1)
    raise TimeoutError("the viewer did not get there")


def view_of(viewer: Any, job_id: str) -> Any:
    """The server-side view of the tab showing ``job_id``."""

    def showing() -> list[Any]:
        return [v for v in list(viewer.views.values()) if v.job_id == job_id]

    wait(lambda: bool(showing()))
    return showing()[0]


def aim(view: Any, panel: str, row: int, back: np.ndarray, distance: float = 2.5) -> None:
    """Look at ``row`` of ``panel`` from ``back``, once the browser draws it (a click sent
    before would go through the old pose)."""
    target = view.data.xyz[row].astype(np.float64) + np.asarray(view.panels.frames[panel].position)
    view.camera.place(target + distance * back, target)
    wait(view.camera.applied)
    time.sleep(0.5)


def click_centre(page: Any) -> None:
    canvas = page.locator("canvas")
    box = max(
        (canvas.nth(i).bounding_box() for i in range(canvas.count())),
        key=lambda b: b["width"] * b["height"],
    )
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)


def in_sight(view: Any, row: int, back: np.ndarray) -> bool:
    """Whether nothing drawn (the ceiling is hidden) lies in front of ``row`` along ``back``."""
    data = view.data
    rel = data.xyz.astype(np.float64) - data.xyz[row]
    along = rel @ back
    off = np.linalg.norm(rel - along[:, None] * back, axis=1)
    return not np.any((along > 0.15) & (off < 0.2) & (data.fused != 0))


def top_row(view: Any, label: int, back: np.ndarray) -> int:
    """A fused-panel row of class ``label`` with nothing drawn in front of it along ``back``."""
    rows = np.flatnonzero(view.data.fused == label)
    found = (int(i) for i in np.random.default_rng(1).permutation(rows)[:300])
    return next((i for i in found if in_sight(view, i, back)), int(rows[0]))


def shooter(page: Any, out: Path, shots: list[Path]) -> Any:
    """``shot(name)``: the page, once it has had a moment to draw, as ``out/name``."""

    def shot(name: str, settle: float = 1.5) -> None:
        time.sleep(settle)
        page.screenshot(path=str(out / name))
        shots.append(out / name)

    return shot


def sign_in(page: Any, key: str) -> None:
    """Type ``key`` into the viewer's sign-in box and wait for the job it opens."""
    page.get_by_text("API key", exact=True).locator(
        "xpath=ancestor::div[contains(@class, 'mantine-Flex-root')][1]"
    ).locator("input").first.fill(key)
    page.get_by_role("button", name="Sign in").click()
    page.get_by_text("points shown").wait_for(timeout=120_000)


def tour(page: Any, viewer: Any, out: Path) -> list[Path]:
    """Sign in, every panel, a pick, a measure; then :func:`tour_views`; the pictures made."""
    shots: list[Path] = []
    shot = shooter(page, out, shots)
    page.goto(viewer.link("area6_office_4"))
    page.add_style_tag(content=HIDE_TOASTS)
    page.get_by_text("This viewer needs a key").wait_for(timeout=60_000)
    shot("viewer_sign_in.png")
    sign_in(page, KEY)
    for box in ("Segments panel", "Confidence panel", "Error map panel"):
        page.get_by_label(box, exact=True).check()
    shot("viewer_all_panels.png", 3.0)
    for box in ("Segments panel", "Confidence panel", "Error map panel"):
        page.get_by_label(box, exact=True).uncheck()
    view = view_of(viewer, "area6_office_4")
    back = np.array([0.0, -0.35, 1.0]) / np.linalg.norm([0.0, -0.35, 1.0])
    time.sleep(1.0)
    aim(view, "fused", top_row(view, 7, back), back, 5.0)  # a table top
    click_centre(page)
    page.get_by_text("height above floor").wait_for(timeout=30_000)
    shot("viewer_pick.png")
    page.get_by_label("Click to", exact=True).click()
    page.get_by_role("option", name="Measure distance").click()
    xyz = view.data.xyz
    a = top_row(view, 1, back)  # two floor points far apart
    floor = np.flatnonzero((view.data.fused == 1) & (np.abs(xyz[:, 2] - xyz[a, 2]) < 0.05))
    far = floor[np.argsort(-np.linalg.norm(xyz[floor] - xyz[a], axis=1))]
    b = next(int(i) for i in far if in_sight(view, int(i), back))
    aim(view, "fused", a, back, 6.0)
    click_centre(page)
    aim(view, "fused", b, back, 6.0)
    click_centre(page)
    page.get_by_text("Distance", exact=False).first.wait_for(timeout=30_000)
    page.get_by_role("button", name="Top").click()
    shot("viewer_measure.png")
    return shots + tour_views(page, view, out)


def tour_views(page: Any, view: Any, out: Path) -> list[Path]:
    """One large panel (errors, in the plan), the confusion table, objects and rooms, the plan
    with its legend and scale bar, a slice, an object of the list; a ScanNet scan."""
    shots: list[Path] = []
    shot = shooter(page, out, shots)
    page.get_by_label("Layout", exact=True).click()
    page.get_by_role("option", name="One large panel").click()
    page.get_by_label("Panel", exact=True).click()
    page.get_by_role("option", name="Errors").click()
    page.get_by_role("button", name="Top").click()
    shot("viewer_single_errors_top.png")
    page.get_by_text("Confusion", exact=True).scroll_into_view_if_needed()
    shot("viewer_confusion.png")
    page.get_by_label("Layout", exact=True).click()
    page.get_by_role("option", name="Row of panels").click()
    page.get_by_role("button", name="Fit all").click()
    page.get_by_text("Objects and rooms", exact=True).scroll_into_view_if_needed()
    shot("viewer_objects.png")
    page.get_by_role("button", name="Top").click()  # the plan: legend and scale bar
    wait(view.camera.applied)
    shot("viewer_plan.png")
    print(f"screenshot at 2x the canvas: {timed_screenshot(page):.2f} s (click to file)")
    page.get_by_text("Clip and slice", exact=True).click()
    page.get_by_label("Slice", exact=True).check()
    page.get_by_text("clipped to").wait_for(timeout=60_000)
    page.mouse.move(5, 5)  # no tooltip over the picture
    shot("viewer_slice.png", 3.0)
    page.get_by_label("Slice", exact=True).uncheck()
    page.get_by_text("Clip and slice", exact=True).click()
    biggest = max(view.objects.objects, key=lambda o: o.radius)
    page.get_by_text("Object list", exact=True).scroll_into_view_if_needed()
    page.get_by_role("button", name=biggest.label, exact=True).click()
    page.get_by_text(f"Selected: {biggest.name}").wait_for(timeout=30_000)
    wait(view.camera.applied)
    page.get_by_role("button", name="Fit all").click()
    page.get_by_role("button", name=biggest.label, exact=True).scroll_into_view_if_needed()
    page.mouse.move(5, 5)
    shot("viewer_object_list.png", 3.0)
    # a ScanNet scan with the confidence panel, chosen in the same tab's picker
    page.get_by_label("Job", exact=True).click()
    page.get_by_role("option", name="scene0002_00.ply", exact=False).click()
    page.locator("strong", has_text="scene0002_00.ply").wait_for(timeout=60_000)
    page.get_by_label("Confidence panel", exact=True).check()
    page.get_by_role("button", name="Fit all").click()
    shot("viewer_scannet_confidence.png", 3.0)
    return shots


def timed_screenshot(page: Any) -> float:
    """Seconds from a click on *Screenshot (PNG)* (2x the canvas) to the file in the browser."""
    started = time.perf_counter()
    with page.expect_download(timeout=120_000) as info:
        page.get_by_role("button", name="Screenshot (PNG)").click()
    info.value.path()
    return time.perf_counter() - started


def service_pictures(browser: Any, root: Path) -> list[Path]:
    """The job page and the viewer as a user meets them: ``jointseg serve`` with an API key, a
    real S3DIS room uploaded on the job page, segmented, its view link opened."""
    from helpers.service import free_port as service_port
    from helpers.service import start_service

    data = Path(tempfile.mkdtemp(prefix="tour_service_"))
    proc, url = start_service(
        data, 1, wait_s=120, key=KEY, viewer_port=service_port(), JOINTSEG_API_KEYS=KEY
    )
    shots = [root / "docs" / "job_page.png", root / "docs" / "viewer.png"]
    downloads = root / "docs" / "images" / "job_page_downloads.png"
    try:
        page = browser.new_page(viewport={"width": 1400, "height": 700}, accept_downloads=True)
        page.goto(url + "/")
        page.fill("#api-key", KEY)
        page.click("#save-key")
        page.set_input_files("#scan-file", str(SCANS["area6_office_4"]))
        page.click("#upload")
        page.wait_for_selector("tr[data-status=succeeded]", timeout=900_000)
        page.screenshot(path=str(shots[0]))
        row = page.locator("tr[data-status=succeeded]").first
        row.get_by_role("button", name="download", exact=True).click()
        row.get_by_role("button", name="IFC", exact=True).wait_for(timeout=5_000)
        page.screenshot(path=str(downloads))
        page.locator("h1").click()  # closes the menu
        with page.expect_popup() as popup:
            row.locator("a.view-link").click()
        viewer = popup.value
        viewer.set_viewport_size({"width": 1600, "height": 900})
        viewer.add_style_tag(content=HIDE_TOASTS)
        viewer.get_by_text("This viewer needs a key").wait_for(timeout=60_000)
        sign_in(viewer, KEY)
        time.sleep(4.0)
        viewer.screenshot(path=str(shots[1]))
    finally:
        proc.terminate()
        proc.wait(60)
    return [*shots, downloads]


def ifc_picture(root: Path) -> Path:
    """The IFC model of a synthetic 3-room floor through IfcOpenShell (bench/ifc_view.py)."""
    from ifc_view import make_model, render  # bench/ifc_view.py: this folder is on the path

    out = root / "docs" / "images" / "ifc_floor.png"
    print(render(make_model(Path(tempfile.mkdtemp(prefix="tour_ifc_"))), out), "->", out)
    return out


def frame_rate(browser: Any, budgets: list[int], seconds: float, cache: Path) -> list[tuple]:
    """Frames per second while orbiting a 300 k-point result with five panels, per budget."""
    from viewer import make_big_result  # bench/viewer.py: this folder is on the path

    from web.sources import DirectorySource
    from web.viewer import Viewer

    big = make_big_result(300_000, cache)
    folder = Path(tempfile.mkdtemp(prefix="tour_fps_"))
    (folder / "big.ply").write_bytes(big.read_bytes())
    viewer = Viewer(DirectorySource(folder), port=free_port())
    rows = []
    try:
        for budget in budgets:
            rows.append(_orbit_rate(browser, viewer, budget, seconds))
    finally:
        viewer.stop()
    return rows


def _orbit_rate(browser: Any, viewer: Any, budget: int, seconds: float) -> tuple:
    """(budget, points per panel sent, points drawn, frames per second) for one budget."""
    page = browser.new_page(viewport={"width": 1600, "height": 900})
    page.goto(viewer.link("big"))
    page.get_by_text("points shown").wait_for(timeout=120_000)
    from web.scene import SEGMENTS

    view = view_of(viewer, "big")
    view.ui.panel_boxes[SEGMENTS].value = True
    view.ui.budget.value = budget
    wait(lambda: view.panels.shown is None or view.panels.shown.size <= budget, 120)
    time.sleep(3.0)
    sent = sum(n.points.shape[0] for k, n in view.panels.nodes.items() if k[0] == "fused")
    stop = threading.Event()
    camera = view.client.camera
    centre, radius = (
        np.asarray(camera.look_at),
        float(np.linalg.norm(np.asarray(camera.position) - np.asarray(camera.look_at))),
    )
    height = float(np.asarray(camera.position)[2])

    def orbit() -> None:
        angle = -math.pi / 2
        while not stop.is_set():
            angle += 0.05
            flat = radius * 0.5
            camera.position = (
                centre[0] + flat * math.cos(angle),
                centre[1] + flat * math.sin(angle),
                height,
            )
            time.sleep(0.05)

    mover = threading.Thread(target=orbit, daemon=True)
    mover.start()
    frames = page.evaluate(
        """(ms) => new Promise(done => { let n = 0; const end = performance.now() + ms;
           const step = () => { n++; if (performance.now() < end)
           requestAnimationFrame(step); else done(n); }; requestAnimationFrame(step); })""",
        int(seconds * 1000),
    )
    stop.set()
    mover.join()
    page.close()
    return (budget, sent, 5 * sent, frames / seconds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--cache", type=Path, default=ROOT / "bench" / "_cache")
    ap.add_argument("--budgets", default="300000,100000,30000")
    ap.add_argument("--seconds", type=float, default=6.0)
    ap.add_argument("--no-fps", action="store_true", help="the pictures only")
    args = ap.parse_args()
    header()
    from playwright.sync_api import sync_playwright

    from web.pictures import write_record
    from web.sources import DirectorySource
    from web.viewer import Viewer

    out = ROOT / "docs" / "images"
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=ARGS)
        try:
            pictures = service_pictures(browser, ROOT)
            folder = Path(tempfile.mkdtemp(prefix="tour_"))
            segmented(folder, args.cache)
            viewer = Viewer(DirectorySource(folder), port=free_port(), authorise=lambda k: k == KEY)
            page = browser.new_page(viewport={"width": 1600, "height": 900}, accept_downloads=True)
            try:
                pictures += tour(page, viewer, out)
            finally:
                page.close()
                viewer.stop()
            pictures.append(ifc_picture(ROOT))
            for path in pictures:
                print(f"wrote {path.relative_to(ROOT)}")
            print(f"wrote {write_record(ROOT, pictures).relative_to(ROOT)}")
            if args.no_fps:
                return
            budgets = [int(b) for b in args.budgets.split(",")]
            rows = frame_rate(browser, budgets, args.seconds, args.cache)
        finally:
            browser.close()
    print("\n| point budget per panel | points per panel sent | points drawn (5 panels) | "
          "frames per second while orbiting |")  # fmt: skip
    print("|---|---|---|---|")
    for budget, sent, drawn, fps in rows:
        print(f"| {budget:,} | {sent:,} | {drawn:,} | {fps:.1f} |")


if __name__ == "__main__":
    main()
