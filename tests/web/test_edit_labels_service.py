"""Saving corrections from the viewer to the job service, in Debian's headless chromium (issue
63): the tab's edit saved is the API's labels version 1 (``GET /v1/jobs/{id}/labels``, the
result's ``fused_label``), a reload of the page shows it, and a save that another user's came
before is refused with an offer to reload, which shows theirs.

The service is its database and data folder with one succeeded job (the result the viewer tests
share), the API in process (``TestClient``), the viewer on a ServiceSource of the same folder.
"""

from __future__ import annotations

import shutil
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from jointseg.io import read_scan
from tests.support.shots import settled
from tests.support.viewer_pages import free_port, open_tab, view_of, wait_for
from tests.web.test_edit_labels_browser import choose, fused_count, key_of
from tests.web.test_viewer_tools_browser import BACK, aim, answer, clear_point, click_centre
from web.selection import SEGMENT


@pytest.fixture
def served(jobs: Path, tmp_path: Path) -> Iterator[tuple[Any, Any, str]]:
    """The API (a TestClient), a viewer on the same service, and the id of its one job."""
    from fastapi.testclient import TestClient

    from server.api.app import create_app
    from server.settings import Settings
    from server.state.db import init_db, make_engine, make_sessions
    from server.state.jobs import create_job
    from server.state.models import Job
    from server.storage import Storage
    from web.service_source import ServiceSource
    from web.viewer import Viewer

    settings = Settings(data_dir=tmp_path)
    engine = make_engine(settings)
    init_db(engine)
    storage, job_id = Storage(tmp_path), uuid.uuid4().hex
    with make_sessions(engine)() as session:
        create_job(
            session, job_id=job_id, filename="room.ply", fmt="ply", size_bytes=1,
            points=30_000, config={}, network="randlanet",
        )  # fmt: skip
        row = session.get(Job, job_id)
        assert row is not None
        row.status = "succeeded"
        session.commit()
    storage.job_dir(job_id).mkdir(parents=True)
    shutil.copy(jobs / "room.ply", storage.result_path(job_id))
    shutil.copy(jobs / "room.report.json", storage.report_path(job_id))
    source = ServiceSource(settings)
    viewer = Viewer(source, port=free_port())
    try:
        with TestClient(create_app(settings)) as api:
            yield api, viewer, job_id
    finally:
        viewer.stop()
        source.close()
        engine.dispose()


def test_a_saved_edit_is_the_apis_version_1_and_a_reload_shows_it(
    browser: Any, served: tuple[Any, Any, str], tmp_path: Path
) -> None:
    api, viewer, job_id = served
    page = open_tab(browser, viewer.link(job_id))
    try:
        page.get_by_text("points shown").wait_for(timeout=30_000)
        settled(page)
        view = view_of(viewer, job_id)
        page.get_by_text("Labels version 0 (").wait_for(timeout=10_000)
        choose(page, "Select", SEGMENT)
        data = view.data
        first = clear_point(data, view.panels.drawn_rows("fused"), BACK, 0.25)
        aim(page, view, "fused", first, BACK)
        click_centre(page)
        seg = int(answer(page, r"Selected: segment (\d+)").group(1))
        scan = read_scan(viewer.source.result_path(job_id))
        members = scan.fields["segment"] == seg
        labels = scan.fields["fused_label"][members]
        target = 8 if int(np.bincount(labels).argmax()) != 8 else 7
        expected = fused_count(page, target) + int(np.count_nonzero(labels != target))
        page.keyboard.press(key_of(target))
        wait_for(lambda: fused_count(page, target) == expected, what="the edit")

        page.get_by_role("button", name="Save").click()
        page.get_by_text("Labels version 1 (").wait_for(timeout=30_000)
        page.get_by_text("no unsaved edits").wait_for(timeout=10_000)
        state = api.get(f"/v1/jobs/{job_id}/labels")
        assert state.status_code == 200 and state.json()["version"] == 1
        assert state.headers["etag"] == '"v1"'
        result = api.get(f"/v1/jobs/{job_id}/result")
        assert result.status_code == 200
        (tmp_path / "v1.ply").write_bytes(result.content)
        saved = read_scan(tmp_path / "v1.ply")
        assert np.all(saved.fields["fused_label"][members] == target)
        assert np.array_equal(
            saved.fields["fused_label"][~members], scan.fields["fused_label"][~members]
        )

        # the viewer's downloads are the saved version's, named for it
        from web.downloads import download_body, file_name

        (tmp_path / "viewer.ply").write_bytes(download_body(viewer.source, job_id, "ply"))
        shown = read_scan(tmp_path / "viewer.ply")
        assert np.all(shown.fields["user_label"][members] == target)
        assert file_name("office.e57", job_id, "laz", 1) == "office_segmented_v1.laz"

        # a reload of the page shows the saved version, from the service
        page.reload()
        page.get_by_text("points shown").wait_for(timeout=30_000)
        page.get_by_text("Labels version 1 (").wait_for(timeout=30_000)
        again = view_of(viewer, job_id, exclude=(view,))
        assert np.all(again.data.fused[again.data.segments == seg] == target)
        wait_for(lambda: fused_count(page, target) == expected, what="the saved count")

        # another user saves version 2; this tab's next save is refused and offers a reload
        other = {"edits": [{"segments": [seg], "label": "clutter"}]}
        patched = api.patch(f"/v1/jobs/{job_id}/labels", json=other, headers={"If-Match": '"v1"'})
        assert patched.status_code == 200, patched.text
        choose(page, "Select", SEGMENT)
        aim(page, again, "fused", first, BACK)
        click_centre(page)
        answer(page, r"Selected: segment \d+")
        page.keyboard.press(key_of(7 if target == 8 else 8))
        page.get_by_text("1 unsaved edit").wait_for(timeout=10_000)
        page.get_by_role("button", name="Save").click()
        page.get_by_text("Someone else saved these labels first").first.wait_for(timeout=10_000)
        page.get_by_role("button", name="Reload saved labels").click()
        page.get_by_text("Labels version 2 (").wait_for(timeout=30_000)
    finally:
        page.close()
