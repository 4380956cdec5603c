"""The job page's routes on the real API app (SQLite in a temporary data directory)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

import web
from server.api.app import create_app
from server.serve_parts import load_serve_parts
from server.settings import Settings
from web.page import VIEWER_FILE, job_page_router
from web.serve import service_parts


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    app = create_app(Settings(data_dir=tmp_path, viewer_port=8123, api_keys=["secret"]))
    app.include_router(job_page_router())
    with TestClient(app) as test_client:
        yield test_client


def test_page_is_plain_html_with_upload_form_and_job_table(client: TestClient) -> None:
    response = client.get("/")  # public: the page holds no data, the API behind it needs keys
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/html")
    html = response.text
    for needle in (
        'id="upload-form"',
        'type="file"',
        'id="network"',
        'id="jobs"',
        'id="api-key"',
        'src="/web/jobs.js"',
        'href="/web/style.css"',
    ):
        assert needle in html
    assert client.get("/v1/jobs").status_code == 401


def test_assets_are_served_and_nothing_else(client: TestClient) -> None:
    js = client.get("/web/jobs.js")
    assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript")
    assert "/v1/jobs" in js.text and "Authorization" in js.text and "localStorage" in js.text
    assert client.get("/web/style.css").headers["content-type"].startswith("text/css")
    for name in ("index.html", "..%2Fpage.py", "missing.js", "..%2F..%2Fpyproject.toml"):
        response = client.get(f"/web/{name}")
        assert response.status_code == 404, name
        assert "[build-system]" not in response.text
    assert "no such page asset" in client.get("/web/missing.js").json()["detail"]


def test_config_gives_the_viewer_port_recorded_by_the_viewer(
    client: TestClient, tmp_path: Path
) -> None:
    body = client.get("/web/config.json").json()
    assert body["viewer_port"] == 8123
    (tmp_path / VIEWER_FILE).write_text(json.dumps({"port": 8125, "pid": 1}))
    assert client.get("/web/config.json").json()["viewer_port"] == 8125


def test_config_offers_only_the_networks_with_weights_here(
    client: TestClient,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    dgcnn_random_weights: Path,
) -> None:
    """DGCNN has no bundled weights: offered once they are configured, at the next load."""
    monkeypatch.setenv("JOINTSEG_CACHE", str(tmp_path / "empty-cache"))
    monkeypatch.delenv("JOINTSEG_DGCNN_WEIGHTS", raising=False)
    assert client.get("/web/config.json").json()["networks"] == ["randlanet"]
    monkeypatch.setenv("JOINTSEG_DGCNN_WEIGHTS", str(dgcnn_random_weights))
    assert client.get("/web/config.json").json()["networks"] == ["randlanet", "dgcnn"]


def test_service_parts_give_the_page_router_and_the_viewer_process() -> None:
    routers, processes = service_parts()
    paths = {route.path for router in routers for route in router.routes}  # type: ignore[attr-defined]
    assert {"/", "/web/config.json", "/web/{name}"} <= paths
    assert [p.__name__ for p in processes] == ["run_viewer"]


def test_serve_finds_the_viewer_through_its_entry_point() -> None:
    """`jointseg serve` gets web's parts from the installed entry point, never by importing web
    from server (pip install -e . registers it)."""
    parts = load_serve_parts()
    paths = {route.path for router in parts.routers for route in router.routes}  # type: ignore[attr-defined]
    assert {"/", "/web/config.json"} <= paths
    assert [p.__module__ + "." + p.__name__ for p in parts.processes] == ["web.serve.run_viewer"]


def test_the_job_page_shows_tiles_done_of_total_when_the_api_gives_them(browser: Any) -> None:
    """In Debian's chromium, on the page's own files, with the API's answers made up: a tiled
    job shows "tiles done/total" (and how many run), one with `tiles: null` or without the
    field (a service from before tiles) shows no tiles note."""
    static = Path(web.__file__).parent / "static"
    base = "http://jobpage.test"
    job = {
        "filename": "floor.laz",
        "format": "laz",
        "points": 20_000_000,
        "network": "randlanet",
        "created_at": "2026-11-24T06:00:00Z",
        "progress": 0.4,
    }
    items = [
        {**job, "id": "a" * 32, "status": "running", "stage": "tiles 3/8",
         "tiles": {"total": 8, "done": 3, "running": 2}},
        {**job, "id": "b" * 32, "status": "succeeded", "stage": "write", "progress": 1.0,
         "tiles": {"total": 8, "done": 8, "running": 0}},
        {**job, "id": "c" * 32, "status": "running", "stage": "network", "tiles": None},
        {**job, "id": "d" * 32, "status": "queued", "stage": None},  # no tiles field at all
    ]  # fmt: skip
    answers = {
        "/": ("text/html", (static / "index.html").read_bytes()),
        "/web/jobs.js": ("text/javascript", (static / "jobs.js").read_bytes()),
        "/web/style.css": ("text/css", (static / "style.css").read_bytes()),
        "/web/config.json": (
            "application/json",
            json.dumps({"viewer_port": 8080, "networks": ["randlanet"]}).encode(),
        ),
        "/v1/jobs": (
            "application/json",
            json.dumps({"items": items, "total": len(items)}).encode(),
        ),
    }

    def answer(route: Any) -> None:
        path = route.request.url[len(base) :].split("?")[0]
        kind, body = answers[path]
        route.fulfill(status=200, content_type=kind, body=body)

    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    try:
        page.route(f"{base}/**", answer)
        page.goto(f"{base}/")
        page.wait_for_selector("tr[data-job-id]", timeout=15_000)

        def progress(job_id: str) -> str:
            return str(page.locator(f'tr[data-job-id="{job_id}"] [data-col=progress]').inner_text())

        assert "tiles 3/8, 2 running" in progress("a" * 32)
        assert "40%" in progress("a" * 32)
        assert progress("a" * 32).count("tiles") == 1  # the stage "tiles 3/8" is not repeated
        assert "tiles 8/8" in progress("b" * 32) and "running" not in progress("b" * 32)
        assert "tiles" not in progress("c" * 32) and "network 40%" in progress("c" * 32)
        assert "tiles" not in progress("d" * 32)
        assert errors == []
    finally:
        page.close()


def test_the_frame_box_shows_the_decision_flags_a_warning_and_posts_a_flip_with_the_key(
    browser: Any,
) -> None:
    """Issue 63, on the page's own files with the API's answers made up: a finished job's
    *frame* button shows the frame stage's decision (up axis, tilt, units, each with its
    confidence) with its warning highlighted; *flip* and a unit chosen, *Re-run with this
    frame* posts them to ``/v1/jobs/{id}/rerun`` with the saved key and links the new job."""
    static = Path(web.__file__).parent / "static"
    base, old, new = "http://jobpage.test", "e" * 32, "f" * 32
    job = {"id": old, "filename": "office.ply", "format": "ply", "points": 30_000,
           "network": "randlanet", "created_at": "2026-12-06T06:00:00Z", "progress": 1.0,
           "status": "succeeded"}  # fmt: skip
    frame = {
        "up": {"axis": "+y", "tilt_degrees": 1.234, "levelled": True, "confidence": 0.41,
               "how": "weighed: the geometry"},
        "units": {"unit": "mm", "metres_per_unit": 0.001, "how": "scale", "confidence": 0.93},
        "warnings": ["up axis unsure (+y, confidence 0.41): check the labels, or set it with --up"],
    }  # fmt: skip
    posted: list[tuple[str, str | None, Any]] = []
    rerun = {**job, "id": new, "status": "queued", "progress": 0.0, "rerun_of": old}

    def answer(route: Any) -> None:
        request = route.request
        path = request.url[len(base) :].split("?")[0]
        files = {"/": "index.html", "/web/jobs.js": "jobs.js", "/web/style.css": "style.css"}
        if path in files:
            kind = {"html": "text/html", "js": "text/javascript", "css": "text/css"}
            body = (static / files[path]).read_bytes()
            route.fulfill(status=200, content_type=kind[files[path].split(".")[1]], body=body)
            return
        answers = {
            "/web/config.json": {"viewer_port": 8080, "networks": ["randlanet"]},
            "/v1/jobs": {"items": [rerun, job] if posted else [job], "total": 1 + len(posted)},
            f"/v1/jobs/{old}": job,
            f"/v1/jobs/{old}/report": {"frame": frame},
        }
        if request.method == "POST" and path == f"/v1/jobs/{old}/rerun":
            posted.append((path, request.headers.get("authorization"), request.post_data_json))
            route.fulfill(status=201, content_type="application/json", body=json.dumps(rerun))
            return
        route.fulfill(status=200, content_type="application/json", body=json.dumps(answers[path]))

    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    try:
        page.route(f"{base}/**", answer)
        page.goto(f"{base}/")
        page.fill("#api-key", "frame-key")
        page.click("#save-key")
        page.locator(f'tr[data-job-id="{old}"]').get_by_role("button", name="frame").click()
        box = page.locator("#frame-box")
        box.get_by_text("confidence 0.41").first.wait_for(timeout=15_000)

        def row(field: str) -> Any:
            return box.locator(f'#frame-decision tr[data-field="{field}"]')

        assert "+y" in row("up").inner_text() and "confidence 0.41" in row("up").inner_text()
        assert "1.2°" in row("tilt").inner_text() and "levelled" in row("tilt").inner_text()
        assert "mm" in row("units").inner_text() and "confidence 0.93" in row("units").inner_text()
        # the warning shown, highlighted: the box and the up axis's row say "unsure"
        assert "up axis unsure" in box.locator("#frame-warnings").inner_text()
        assert box.locator("#frame-unsure").is_visible()
        assert "unsure" in (row("up").get_attribute("class") or "")
        assert "unsure" not in (row("units").get_attribute("class") or "")
        # the controls start at the decision; flip, a unit, one action
        assert page.input_value("#frame-up") == "+y" and page.input_value("#frame-units") == "mm"
        page.click("#frame-flip")
        assert page.input_value("#frame-up") == "-y"
        page.select_option("#frame-units", "cm")
        page.click("#frame-rerun")
        link = page.locator("#frame-new-job")
        link.wait_for(timeout=15_000)
        assert posted == [
            (f"/v1/jobs/{old}/rerun", "Bearer frame-key", {"frame": {"up": "-y", "units": "cm"}})
        ]
        assert link.get_attribute("data-job-id") == new
        page.locator(f'tr[data-job-id="{new}"]').wait_for(timeout=15_000)
        assert "re-run" in page.locator(f'tr[data-job-id="{new}"] [data-col=file]').inner_text()
        # the viewer's link opens the box with its choices preset
        page.goto(f"{base}/#frame={old}&up=-z&units=ft")
        box.get_by_text("confidence 0.41").first.wait_for(timeout=15_000)
        wait = page.wait_for_function
        wait("document.getElementById('frame-up').value === '-z'", timeout=15_000)
        assert page.input_value("#frame-units") == "ft"
        assert errors == []
    finally:
        page.close()
