"""The whole product in a real browser: `jointseg serve` (API, worker, viewer) with API keys on,
a scan uploaded through the job page, the job followed to `succeeded`, its viewer link opened;
and the job page's own behaviour on a real service: only networks with weights offered (the
service's weights cache is empty, so DGCNN has none), a failed job's long error, the empty list,
no key in any link; a view link opened with another tenant's key does not show the job.

The screenshots land in the test artefacts (tests/artifacts or $PYTEST_ARTIFACTS); the
documentation's pictures of the same pages are made by bench/viewer_tour.py.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, quote, urlsplit

import httpx
import numpy as np
import pytest

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.io import read_scan, write_scan
from jointseg.network import published
from jointseg.synth import make_room
from tests.support.download_checks import PAGE_BUTTONS, SUFFIXES, VIEWER_BUTTONS, parsed
from tests.support.shots import HIDE_OVERLAYS, VIEWPORT, palette_pixels, panel_spans, settled
from tests.support.viewer_pages import free_port, key_in, sign_in
from web.frame_panel import flipped

JOINTSEG = str(Path(sys.executable).parent / "jointseg")
API_KEY = "viewer-test-key"
#: A second accepted key with the characters a URL must escape; an admin key, so it sees the
#: jobs API_KEY submitted (tenants: any other key sees only its own).
SPECIAL_KEY = "job+page/key=1&x"
#: Another tenant: an accepted key that sees only its own jobs (none of API_KEY's).
OTHER_KEY = "other-tenant-key"
FINAL = ("succeeded", "failed", "cancelled")


@dataclass
class Running:
    url: str
    viewer_port: int
    process: subprocess.Popen[bytes]
    log: Path

    def client(self) -> httpx.Client:
        headers = {"Authorization": f"Bearer {API_KEY}"}
        return httpx.Client(base_url=self.url, headers=headers, timeout=60)


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Running]:
    """`jointseg serve` with one worker, the viewer on its own port, API keys, and an empty
    weights cache (DGCNN has no weights there; RandLA-Net's are bundled)."""
    data = tmp_path_factory.mktemp("service")
    cache = tmp_path_factory.mktemp("empty-cache")
    port, viewer_port = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("JOINTSEG_")}
    env.update(
        JOINTSEG_DATA_DIR=str(data),
        JOINTSEG_CACHE=str(cache),
        JOINTSEG_API_KEYS=f"{API_KEY},{OTHER_KEY}",
        JOINTSEG_ADMIN_KEYS=SPECIAL_KEY,
        JOINTSEG_TORCH_THREADS="1",
        JOINTSEG_QUEUE_POLL_S="0.2",
        # the folder of the weights fixtures (tests/conftest.py): the jobs name files there
        JOINTSEG_WEIGHTS_DIRS=json.dumps([os.environ["JOINTSEG_TEST_WEIGHTS_DIR"]]),
    )
    log = data / "serve.log"
    with open(log, "wb") as out:
        process = subprocess.Popen(
            [JOINTSEG, "serve", "--port", str(port), "--viewer-port", str(viewer_port),
             "--workers", "1"],
            env=env, stdout=out, stderr=subprocess.STDOUT,
        )  # fmt: skip
    running = Running(f"http://127.0.0.1:{port}", viewer_port, process, log)
    try:
        deadline = time.monotonic() + 90
        while True:
            assert process.poll() is None, log.read_text()[-3000:]
            try:
                # with the key: without one a locked service says only whether it is up
                health = httpx.get(
                    f"{running.url}/healthz",
                    headers={"Authorization": f"Bearer {API_KEY}"},
                    timeout=5,
                ).json()
                viewer_up = httpx.get(f"http://127.0.0.1:{viewer_port}/", timeout=5)
                if health.get("workers") and viewer_up.status_code == 200:
                    break
            except (httpx.HTTPError, ValueError):
                pass
            assert time.monotonic() < deadline, log.read_text()[-3000:]
            time.sleep(0.3)
        yield running
    finally:
        process.send_signal(signal.SIGTERM)
        try:
            process.wait(60)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def test_upload_on_the_job_page_then_inspect_the_result_in_the_viewer(
    service: Running, browser: Any, artifacts: Path, tmp_path: Path
) -> None:
    scan = write_scan(make_room(6, points=30_000), tmp_path / "office.ply")
    page = browser.new_page(viewport={"width": 1400, "height": 700}, accept_downloads=True)
    try:
        page.goto(service.url + "/")
        # API keys are on: the page says so until one is saved, then uploads and lists work
        page.get_by_text("this service needs an API key").wait_for(timeout=15_000)
        page.fill("#api-key", API_KEY)
        page.click("#save-key")
        page.set_input_files("#scan-file", str(scan))
        page.select_option("#network", "randlanet")
        page.click("#upload")
        # accepted: its row appears ("job ... queued" may be gone already, once a worker took it)
        row = page.locator("tr[data-job-id]", has_text="office.ply").first
        row.locator("progress").wait_for(timeout=30_000)
        page.wait_for_selector("tr[data-status=succeeded]", timeout=180_000)
        # "job ... queued" no longer holds: the line is cleared, the row tells the status
        assert page.locator("#upload-status").inner_text() == ""
        (artifacts / "service_job_page.png").write_bytes(page.screenshot())
        assert row.locator("[data-col=status]").inner_text() == "succeeded"
        assert row.locator("[data-col=file]").inner_text() == "office.ply"
        assert "100%" in row.locator("[data-col=progress]").inner_text()
        assert row.locator("[data-col=points]").inner_text() == "30,000"
        job_id = row.get_attribute("data-job-id")
        assert job_id

        # the result the viewer must show, fetched through the API
        with service.client() as http:
            result = http.get(f"/v1/jobs/{job_id}/result")
            assert result.status_code == 200
        path = tmp_path / "result.ply"
        path.write_bytes(result.content)
        labelled = read_scan(path)
        # the page's download (fetch with the key, then a blob) gives the same bytes
        with page.expect_download(timeout=30_000) as download:
            _menu_item(row, "PLY").click()
        assert download.value.suggested_filename == "office_segmented.ply"
        assert Path(download.value.path()).read_bytes() == result.content

        # the job's link opens the viewer on this job, in a new tab; the link carries no key
        # (issue 44): the viewer asks for one, once
        view_href = row.locator("a.view-link").get_attribute("href")
        assert not key_in(view_href, API_KEY), view_href
        with page.expect_popup() as popup:
            row.locator("a.view-link").click()
        viewer = popup.value
        viewer.set_viewport_size(VIEWPORT)
        viewer.add_style_tag(content=HIDE_OVERLAYS)
        sign_in(viewer, API_KEY)
        viewer.get_by_text("points shown").wait_for(timeout=60_000)
        image = settled(viewer)
        (artifacts / "service_viewer.png").write_bytes(viewer.screenshot())
        spans = panel_spans(image, 4)  # raw, network, fused, ground truth
        for span, field in ((spans[1], "network_label"), (spans[2], "fused_label")):
            labels = labelled.fields[field]
            counts = np.bincount(labels, minlength=NUM_CLASSES)
            seen = palette_pixels(image, span)
            present = [c for c in range(1, NUM_CLASSES) if counts[c] >= 0.03 * labels.size]
            assert len(present) >= 3
            for cls in present:
                assert seen[cls] >= 20, f"{field}: {CLASS_NAMES[cls]} missing, {seen.tolist()}"

        # switching the largest class off removes its colour from both label panels
        counts = np.bincount(labelled.fields["fused_label"], minlength=NUM_CLASSES)
        counts[0] = 0
        off = int(np.argmax(counts))
        viewer.get_by_role("button", name=CLASS_NAMES[off], exact=True).click()
        image = settled(viewer)
        (artifacts / "service_viewer_class_off.png").write_bytes(viewer.screenshot())
        spans = panel_spans(image, 4)
        assert palette_pixels(image, spans[1])[off] == 0
        assert palette_pixels(image, spans[2])[off] == 0
        # the address the view wrote (what a user copies to share) names the job, not the key
        shared = str(viewer.evaluate("location.href"))
        assert "job%2F" + job_id in shared and "h." in shared  # it follows the view
        assert not key_in(shared, API_KEY), shared
        viewer.close()

        # the shared link opened by someone else: their own key, which may not see the job,
        # shows neither the job nor its name
        other = browser.new_page(viewport=VIEWPORT)
        try:
            other.goto(shared)
            sign_in(other, OTHER_KEY)
            other.get_by_text("Cannot show this job").wait_for(timeout=30_000)
            time.sleep(1.0)
            assert other.get_by_text("points shown").count() == 0
            assert other.get_by_text("office.ply").count() == 0
        finally:
            other.close()

        # the viewer needs the API's key too: without one (or with a wrong one) a sign-in box,
        # no job listed, nothing drawn
        base = f"http://127.0.0.1:{service.viewer_port}"
        for query in ("", "?key=not-a-key"):
            ws = f"ws://127.0.0.1:{service.viewer_port}/job/{job_id}{query}"
            locked = browser.new_page(viewport=VIEWPORT)
            try:
                locked.goto(f"{base}/?websocket={quote(ws, safe='')}")
                locked.get_by_text("Enter one of the job service's API keys").wait_for(
                    timeout=60_000
                )
                time.sleep(1.0)
                assert locked.get_by_text("points shown").count() == 0
                assert locked.get_by_text("office.ply").count() == 0
                assert locked.get_by_label("Job", exact=True).count() == 0
            finally:
                locked.close()
    finally:
        page.close()


def _submit(http: httpx.Client, scan: Path, config: dict[str, Any] | None = None) -> httpx.Response:
    """POST /v1/jobs with ``scan`` and an optional job config."""
    data = {"config": json.dumps(config)} if config is not None else None
    with open(scan, "rb") as fh:
        return http.post("/v1/jobs", files={"file": (scan.name, fh)}, data=data)


def _finished(http: httpx.Client, job_id: str, timeout: float = 120.0) -> dict[str, Any]:
    """The job once it is succeeded, failed or cancelled."""
    deadline = time.monotonic() + timeout
    while True:
        job: dict[str, Any] = http.get(f"/v1/jobs/{job_id}").json()
        if job["status"] in FINAL:
            return job
        assert time.monotonic() < deadline, job
        time.sleep(0.2)


def _jobs(http: httpx.Client, tmp_path: Path, random_weights: Path) -> dict[str, dict[str, Any]]:
    """A job that succeeds (the small random network) and one that fails in the worker with a
    long error (a weights file that exists, so the API accepts it, but is no checkpoint)."""
    scan = write_scan(make_room(4, points=3000), tmp_path / "small room.ply")
    garbage = random_weights.parent / f"garbage-{tmp_path.name}.pt"  # in the weights folder
    garbage.write_bytes(b"not a checkpoint")
    configs = {
        "succeeded": {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 0},
        "failed": {"network": {"weights": str(garbage), "device": "cpu"}},
    }
    ids = {}
    for expected, config in configs.items():
        response = _submit(http, scan, config)
        assert response.status_code == 201, response.text
        ids[expected] = response.json()["id"]
    jobs = {expected: _finished(http, job_id) for expected, job_id in ids.items()}
    assert {k: job["status"] for k, job in jobs.items()} == {k: k for k in jobs}
    return jobs


def _open_page(browser: Any, service: Running, key: str = API_KEY) -> Any:
    """The job page with ``key`` saved, its job list loaded."""
    page = browser.new_page(viewport={"width": 1400, "height": 700})
    page.goto(service.url + "/")
    page.fill("#api-key", key)
    page.click("#save-key")
    page.wait_for_function("document.querySelector('#job-count').textContent !== ''")
    return page


def test_an_empty_job_list_says_so(service: Running, browser: Any, tmp_path: Path) -> None:
    with service.client() as http:
        for job in http.get("/v1/jobs", params={"limit": 200}).json()["items"]:
            _finished(http, job["id"])
            assert http.delete(f"/v1/jobs/{job['id']}").status_code == 204
        page = _open_page(browser, service)
        try:
            message = page.locator("#no-jobs")
            message.wait_for(timeout=15_000)
            assert message.inner_text() == "No jobs yet: upload a scan above."
            scan = write_scan(make_room(5, points=2000), tmp_path / "first.ply")
            job = _submit(http, scan).json()
            page.locator(f'tr[data-job-id="{job["id"]}"]').wait_for(timeout=15_000)
            assert not message.is_visible()  # gone with the first job
        finally:
            page.close()
        _finished(http, job["id"])


def test_dgcnn_without_weights_is_not_offered_and_refused_at_submission(
    service: Running, browser: Any, tmp_path: Path
) -> None:
    scan = write_scan(make_room(7, points=2000), tmp_path / "refused.ply")
    page = _open_page(browser, service)
    try:
        page.wait_for_function("document.querySelector('#network').options.length > 0")
        offered = page.eval_on_selector_all("#network option", "els => els.map(e => e.value)")
        assert offered == ["randlanet"]  # dgcnn has no weights on this service

        # a page loaded before the weights went away still offers dgcnn: the API refuses it
        page.evaluate("""() => {
            const option = document.createElement("option");
            option.value = option.textContent = "dgcnn";
            document.querySelector("#network").appendChild(option);
        }""")
        page.set_input_files("#scan-file", str(scan))
        page.select_option("#network", "dgcnn")
        page.click("#upload")
        status = page.locator("#upload-status.error")
        status.wait_for(timeout=30_000)
        pull = f"jointseg models pull {published.DEFAULT_DGCNN}"
        assert "upload refused (422)" in status.inner_text() and pull in status.inner_text()
        # picking another file clears the refusal: it is not about that file
        other = write_scan(make_room(8, points=1000), tmp_path / "other.ply")
        page.set_input_files("#scan-file", str(other))
        assert page.locator("#upload-status").inner_text() == ""
    finally:
        page.close()

    with service.client() as http:
        before = http.get("/v1/jobs").json()["total"]
        response = _submit(http, scan, {"network": {"name": "dgcnn"}})
        assert response.status_code == 422, response.text
        assert response.headers["content-type"] == "application/json"
        assert pull in response.json()["detail"]
        listing = http.get("/v1/jobs", params={"limit": 200}).json()
        assert listing["total"] == before
        assert [j for j in listing["items"] if j["network"] == "dgcnn"] == []


def _boxes(row: Any) -> list[dict[str, float]]:
    """The bounding boxes of a row's action links and buttons."""
    actions = row.locator("[data-col=actions] > *")
    return [actions.nth(i).bounding_box() for i in range(actions.count())]


def test_a_long_job_error_keeps_every_rows_links_on_one_line(
    service: Running, browser: Any, artifacts: Path, tmp_path: Path, random_weights: Path
) -> None:
    with service.client() as http:
        jobs = _jobs(http, tmp_path, random_weights)
    error = jobs["failed"]["error"]
    # one line since job errors are bounded, still longer than the column is wide
    assert len(error) > 120 and "not a readable PyTorch checkpoint" in error
    page = _open_page(browser, service)
    try:
        failed = page.locator(f'tr[data-job-id="{jobs["failed"]["id"]}"]')
        done = page.locator(f'tr[data-job-id="{jobs["succeeded"]["id"]}"]')
        page.wait_for_selector(f'tr[data-job-id="{jobs["failed"]["id"]}"][data-status=failed]')
        done.locator("a.view-link").wait_for(timeout=15_000)
        (artifacts / "service_job_page_failed.png").write_bytes(page.screenshot())
        for row, count in ((done, 4), (failed, 1)):  # view, download, frame, delete / delete
            boxes = _boxes(row)
            assert len(boxes) == count
            assert max(b["y"] for b in boxes) - min(b["y"] for b in boxes) < 2, boxes
            xs = [b["x"] for b in boxes]
            assert xs == sorted(xs), boxes  # side by side, left to right
        # the failed row is one line high, like the others; its error whole in the tooltip
        done_height = done.bounding_box()["height"]
        assert failed.bounding_box()["height"] < 1.5 * done_height
        label = failed.locator("[data-col=progress] .job-error")
        assert label.get_attribute("title") == error
        assert label.evaluate("el => el.scrollWidth > el.clientWidth")  # cut, not wrapped
        # a click unfolds the whole error; the links stay on one line
        label.click()
        assert failed.bounding_box()["height"] > 2 * done_height
        boxes = _boxes(done)
        assert max(b["y"] for b in boxes) - min(b["y"] for b in boxes) < 2, boxes
    finally:
        page.close()


def test_no_link_of_the_job_page_carries_the_key(
    service: Running, browser: Any, tmp_path: Path, random_weights: Path
) -> None:
    with service.client() as http:
        scan = write_scan(make_room(8, points=2000), tmp_path / "keyed.ply")
        config = {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 0}
        job = _finished(http, _submit(http, scan, config).json()["id"])
        assert job["status"] == "succeeded"
    page = _open_page(browser, service, key=SPECIAL_KEY)
    try:
        link = page.locator(f'tr[data-job-id="{job["id"]}"] a.view-link')
        link.wait_for(timeout=15_000)
        href = link.get_attribute("href")
        parts = urlsplit(href)
        assert (parts.scheme, parts.port) == ("http", service.viewer_port)
        assert f"websocket={quote('ws://', safe='')}" in parts.query  # the ws URL stays encoded
        (websocket,) = parse_qs(parts.query)["websocket"]
        # the job, never the key (a link shares a view, not a credential: issue 44)
        assert websocket == f"ws://127.0.0.1:{service.viewer_port}/job/{job['id']}"
        # nor anywhere else: no link, no address of the page, with either key saved
        for key in (SPECIAL_KEY, API_KEY):
            page.fill("#api-key", key)
            page.click("#save-key")
            link.wait_for(timeout=15_000)
            urls = page.eval_on_selector_all(
                "[href], [src], [action]",
                "els => els.map(e => e.href || e.src || e.action || '')",
            )
            urls.append(page.url)
            assert [u for u in urls if key_in(u, key)] == []
    finally:
        page.close()


def _menu_item(row: Any, label: str) -> Any:
    """The job page's download button ``label`` of a row, its menu opened (as a user does)."""
    row.get_by_role("button", name="download", exact=True).click()
    button = row.get_by_role("button", name=label, exact=True)
    button.wait_for(timeout=5_000)
    return button


def _saved(page: Any, button: Any) -> tuple[str, bytes, str]:
    """Click ``button`` and wait for the download it starts: its name, bytes and address."""
    with page.expect_download(timeout=120_000) as info:
        button.click()
    download = info.value
    return download.suggested_filename, Path(download.path()).read_bytes(), download.url


def test_every_download_of_the_job_page_and_the_viewer_parses(
    service: Running, browser: Any, artifacts: Path, tmp_path: Path, random_weights: Path
) -> None:
    """Issue 45, point 1: PLY, LAS, LAZ, report, objects.json and IFC from both pages, as each
    page fetches them (the page: the API with the key in a header; the viewer: over its signed-in
    websocket), the same bytes as the API's routes, and no key in any address either asked."""
    with service.client() as http:
        scan = write_scan(make_room(9, points=3000), tmp_path / "survey hall.ply")
        config = {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 0}
        job = _finished(http, _submit(http, scan, config).json()["id"])
        assert job["status"] == "succeeded"
        base = f"/v1/jobs/{job['id']}"
        routes = {k: f"{base}/result?format={k}" for k in ("ply", "las", "laz", "ifc")}
        routes |= {k: f"{base}/{k}" for k in ("report", "objects")}
        api = {kind: http.get(route) for kind, route in routes.items()}
    assert all(r.status_code == 200 for r in api.values()), {k: r.text for k, r in api.items()}
    addresses: list[str] = []
    page = _open_page(browser, service)
    page.context.on("request", lambda request: addresses.append(request.url))
    page.context.on(  # the viewer's tab: its websocket's address too
        "page", lambda tab: tab.on("websocket", lambda socket: addresses.append(socket.url))
    )
    try:
        row = page.locator(f'tr[data-job-id="{job["id"]}"]')
        row.locator("a.view-link").wait_for(timeout=15_000)
        menu = row.locator(".download-menu")
        _menu_item(row, "IFC")
        (artifacts / "service_job_page_downloads.png").write_bytes(page.screenshot())
        assert [b.inner_text() for b in menu.get_by_role("button").all()] == list(
            PAGE_BUTTONS.values()
        )
        page.locator("h1").click()  # a click elsewhere closes the menu
        assert menu.is_hidden()
        got = {}
        for kind, label in PAGE_BUTTONS.items():
            name, body, url = _saved(page, _menu_item(row, label))
            assert name == "survey hall" + SUFFIXES[kind]
            addresses.append(url)
            got[kind] = parsed(kind, body, 3000)
            if kind == "objects":  # the API's JSON, as the route serialises it
                assert got[kind] == api[kind].json()
            else:
                assert body == api[kind].content, kind
        assert page.locator("#action-status").inner_text() == ""
        assert menu.is_hidden()  # closed once a file was chosen

        with page.expect_popup() as popup:
            row.locator("a.view-link").click()
        viewer = popup.value
        viewer.set_viewport_size(VIEWPORT)
        sign_in(viewer, API_KEY)
        viewer.get_by_text("points shown").wait_for(timeout=60_000)
        for kind, label in VIEWER_BUTTONS.items():
            button = viewer.get_by_role("button", name=label, exact=True)
            name, body, url = _saved(viewer, button)
            assert name == "survey hall" + SUFFIXES[kind]
            addresses.append(url)
            if kind in ("report", "objects"):
                assert parsed(kind, body, 3000) == got[kind]
            else:
                parsed(kind, body, 3000)
                assert body == api[kind].content, kind  # the API's own file
        viewer.close()
    finally:
        page.close()
    assert any("/v1/jobs/" in a for a in addresses) and any(a.startswith("ws") for a in addresses)
    assert [a for a in addresses if key_in(a, API_KEY)] == []


def _picker_options(viewer: Any) -> list[str]:
    """The viewer's job list as the user sees it: the *Job* dropdown opened, read, closed."""
    viewer.get_by_label("Job", exact=True).click()
    options = viewer.get_by_role("option")
    options.first.wait_for(timeout=10_000)
    # read in one go: the list is redrawn when it changes, and an option counted a moment ago
    # may be gone when its text is asked for
    names = [str(n) for n in options.all_inner_texts()]
    viewer.keyboard.press("Escape")
    return names


def _until(check: Any, seconds: float, what: str) -> float:
    """Wait until ``check()`` holds; the seconds it took."""
    started = time.monotonic()
    while not check():
        assert time.monotonic() - started < seconds, f"{what} not within {seconds} s"
        time.sleep(0.3)
    return time.monotonic() - started


def test_a_deleted_job_leaves_the_viewer_without_a_reload(
    service: Running, browser: Any, tmp_path: Path, random_weights: Path
) -> None:
    """Issue 45, point 3: a job deleted through the API leaves the open viewer's list within a
    few seconds; the job the viewer shows, deleted, is taken off the screen with a clear note."""
    config = {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 0}
    with service.client() as http:
        ids = {}
        for name in ("shown", "other"):
            scan = write_scan(make_room(10, points=2000), tmp_path / f"{name}.ply")
            ids[name] = _finished(http, _submit(http, scan, config).json()["id"])["id"]
        base = f"http://127.0.0.1:{service.viewer_port}"
        ws = f"ws://127.0.0.1:{service.viewer_port}/job/{ids['shown']}"
        viewer = browser.new_page(viewport=VIEWPORT)
        sockets: list[str] = []
        viewer.on("websocket", lambda socket: sockets.append(socket.url))
        try:
            viewer.goto(f"{base}/?websocket={quote(ws, safe='')}")
            sign_in(viewer, API_KEY)
            viewer.get_by_text("points shown").wait_for(timeout=60_000)
            listed = _picker_options(viewer)
            assert any(n.startswith("other.ply") for n in listed), listed
            assert any(n.startswith("shown.ply") for n in listed), listed

            assert http.delete(f"/v1/jobs/{ids['other']}").status_code == 204
            took = _until(
                lambda: not any(n.startswith("other.ply") for n in _picker_options(viewer)),
                10,
                "the deleted job leaving the list",
            )
            assert any(n.startswith("shown.ply") for n in _picker_options(viewer))
            assert viewer.get_by_text("points shown").is_visible()  # the shown job stays

            assert http.delete(f"/v1/jobs/{ids['shown']}").status_code == 204
            note = viewer.get_by_text(f"shown.ply [{ids['shown'][:8]}] was deleted")
            note.wait_for(timeout=10_000)
            assert viewer.get_by_text("points shown").count() == 0
            assert not any(n.startswith("shown.ply") for n in _picker_options(viewer))
            # the address no longer opens the deleted job
            viewer.wait_for_function(f"!location.href.includes({json.dumps(ids['shown'])})")
        finally:
            viewer.close()
    assert took < 10
    assert len(sockets) == 1, sockets  # one connection all along: nothing was reloaded


def test_a_flip_in_the_frame_box_reruns_the_job_with_that_up_axis_and_leaves_it_alone(
    service: Running, browser: Any, artifacts: Path, tmp_path: Path, random_weights: Path
) -> None:
    """Issue 63: the job page shows what the frame stage decided; *flip* and *Re-run with this
    frame* make a new job from the stored upload whose frame is the flipped axis, set by the
    user (read back through the API), and the old job stays as it was."""
    with service.client() as http:
        scan = write_scan(make_room(7, points=3000), tmp_path / "flip me.ply")
        config = {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 0}
        old = _finished(http, _submit(http, scan, config).json()["id"])
        assert old["status"] == "succeeded"
        report = http.get(f"/v1/jobs/{old['id']}/report").json()
    decided = report["frame"]["up"]["axis"]
    page = _open_page(browser, service)
    try:
        row = page.locator(f'tr[data-job-id="{old["id"]}"]')
        row.get_by_role("button", name="frame").click()
        box = page.locator("#frame-box")
        box.locator('tr[data-field="up"] [data-part="confidence"]').get_by_text(
            "confidence"
        ).wait_for(timeout=15_000)
        up_row = box.locator('tr[data-field="up"]').inner_text()
        assert decided in up_row and f"{report['frame']['up']['confidence']:.2f}" in up_row
        units_row = box.locator('tr[data-field="units"]').inner_text()
        assert report["frame"]["units"]["unit"] in units_row
        page.click("#frame-flip")
        page.click("#frame-rerun")
        link = page.locator("#frame-new-job")
        link.wait_for(timeout=30_000)
        (artifacts / "service_job_page_frame.png").write_bytes(page.screenshot())
        new_id = link.get_attribute("data-job-id")
        page.locator(f'tr[data-job-id="{new_id}"]').wait_for(timeout=15_000)
    finally:
        page.close()
    with service.client() as http:
        new = _finished(http, str(new_id))
        assert new["status"] == "succeeded", new
        assert new["rerun_of"] == old["id"] and new["filename"] == old["filename"]
        frame = http.get(f"/v1/jobs/{new_id}/report").json()["frame"]
        assert frame["up"]["axis"] == flipped(decided), frame["up"]
        assert frame["up"]["how"] == "set by the user"
        # the old job: the same record and the same report as before
        again = http.get(f"/v1/jobs/{old['id']}").json()
        assert {k: again[k] for k in old if k != "links"} == {
            k: old[k] for k in old if k != "links"
        }
        assert http.get(f"/v1/jobs/{old['id']}/report").json() == report
