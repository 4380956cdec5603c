"""The whole product in a real browser: `jointseg serve` (API, worker, viewer) with API keys on,
a scan uploaded through the job page, the job followed to `succeeded`, its viewer link opened.

The screenshots land in the test artefacts (tests/artifacts or $PYTEST_ARTIFACTS); the
README's viewer screenshot is ``service_viewer.png`` from this test.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from shots import HIDE_TOASTS, palette_pixels, panel_spans, settled

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.io import read_scan, write_scan
from jointseg.synth import make_room

JOINTSEG = str(Path(sys.executable).parent / "jointseg")
API_KEY = "viewer-test-key"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


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
    """`jointseg serve` with one worker, the viewer on its own port and an API key."""
    data = tmp_path_factory.mktemp("service")
    port, viewer_port = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("JOINTSEG_")}
    env.update(
        JOINTSEG_DATA_DIR=str(data),
        JOINTSEG_API_KEYS=API_KEY,
        JOINTSEG_TORCH_THREADS="1",
        JOINTSEG_QUEUE_POLL_S="0.2",
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
                health = httpx.get(f"{running.url}/healthz", timeout=5).json()
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
        page.get_by_text("queued").first.wait_for(timeout=30_000)
        row = page.locator("tr[data-job-id]").first
        row.locator("progress").wait_for(timeout=10_000)
        page.wait_for_selector("tr[data-status=succeeded]", timeout=180_000)
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
            row.get_by_role("button", name="result").click()
        assert download.value.suggested_filename == "office_segmented.ply"
        assert Path(download.value.path()).read_bytes() == result.content

        # the job's link opens the viewer on this job, in a new tab
        with page.expect_popup() as popup:
            row.locator("a.view-link").click()
        viewer = popup.value
        viewer.set_viewport_size({"width": 1600, "height": 900})
        viewer.add_style_tag(content=HIDE_TOASTS)
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
        viewer.get_by_label(CLASS_NAMES[off], exact=True).uncheck()
        image = settled(viewer)
        (artifacts / "service_viewer_class_off.png").write_bytes(viewer.screenshot())
        spans = panel_spans(image, 4)
        assert palette_pixels(image, spans[1])[off] == 0
        assert palette_pixels(image, spans[2])[off] == 0
        viewer.close()
    finally:
        page.close()
