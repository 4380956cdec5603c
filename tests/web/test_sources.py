"""Job sources: a folder of results, and the job service's database and storage."""

from __future__ import annotations

import os
import shutil
import time
import uuid
from pathlib import Path

import pytest

from jointseg.exceptions import AuthenticationError, JobNotFound, JobStateError
from web.sources import DirectorySource


def test_directory_source_lists_results_newest_first(results: Path, tmp_path: Path) -> None:
    for i, name in enumerate(["old", "new"]):
        shutil.copy(results / "labelled.ply", tmp_path / f"{name}.ply")
        os.utime(tmp_path / f"{name}.ply", (time.time() + i, time.time() + i))
    shutil.copy(results / "labelled.report.json", tmp_path / "new.report.json")
    (tmp_path / "notes.txt.bak").write_text("not a result")
    source = DirectorySource(tmp_path)
    jobs = source.finished_jobs()
    assert [j.id for j in jobs] == ["new", "old"]
    assert jobs[0].filename == "new.ply" and "new.ply [new]" in jobs[0].label
    assert source.result_path("old") == tmp_path / "old.ply"
    assert source.report_path("new") == tmp_path / "new.report.json"
    assert source.report_path("old") is None


def test_directory_source_converts_downloads_away_from_the_results(
    results: Path, tmp_path: Path
) -> None:
    import laspy

    shutil.copy(results / "labelled.ply", tmp_path / "room.ply")
    source = DirectorySource(tmp_path)
    assert source.export_path("room", "ply") == tmp_path / "room.ply"  # the file itself
    las = source.export_path("room", "laz")
    assert las.parent != tmp_path and las.is_file()
    assert laspy.read(las).header.point_count == 4000
    assert source.export_path("room", "laz") == las  # made once, kept
    assert [p.name for p in tmp_path.iterdir()] == ["room.ply"]  # nothing new to list
    with pytest.raises(JobStateError, match="no report"):  # the IFC model needs the report
        source.export_path("room", "ifc")
    with pytest.raises(JobNotFound):
        source.export_path("../room", "las")


def test_download_names_follow_the_upload_and_survive_any_characters() -> None:
    from server.results import DOWNLOADS, content_disposition, download_name

    names = [download_name("hall 2.e57", kind) for kind in DOWNLOADS]
    assert names == [
        "hall 2_segmented.ply",
        "hall 2_segmented.las",
        "hall 2_segmented.laz",
        "hall 2_report.json",
        "hall 2_objects.json",
        "hall 2.ifc",
    ]
    assert content_disposition("hall_2.ifc") == 'attachment; filename="hall_2.ifc"'
    # a blank, a quote or a non-ASCII letter goes percent-encoded in filename* (RFC 6266), as
    # Starlette's FileResponse writes it
    assert content_disposition("hall 2.ifc") == "attachment; filename*=utf-8''hall%202.ifc"
    assert content_disposition('Büro "A".ifc', "inline") == (
        "inline; filename*=utf-8''B%C3%BCro%20%22A%22.ifc"
    )


@pytest.mark.parametrize("bad", ["missing", "../labelled", ".hidden", "a/b"])
def test_directory_source_refuses_unknown_ids_and_paths(results: Path, bad: str) -> None:
    with pytest.raises(JobNotFound):
        DirectorySource(results).result_path(bad)


def test_service_source_lists_succeeded_jobs_only(results: Path, tmp_path: Path) -> None:
    from server.settings import Settings
    from server.state.db import init_db, make_engine, make_sessions
    from server.state.jobs import create_job
    from server.state.models import Job
    from server.storage import Storage
    from web.service_source import ServiceSource

    settings = Settings(data_dir=tmp_path)
    engine = make_engine(settings)
    init_db(engine)
    sessions, storage = make_sessions(engine), Storage(tmp_path)
    ids = {status: uuid.uuid4().hex for status in ("succeeded", "running", "gone")}
    with sessions() as session:
        for status, job_id in ids.items():
            create_job(
                session,
                job_id=job_id,
                filename=f"{status}.ply",
                fmt="ply",
                size_bytes=1,
                points=4000,
                config={},
                network="randlanet",
            )
            row = session.get(Job, job_id)
            assert row is not None
            row.status = "running" if status == "running" else "succeeded"
            session.commit()
    for status in ("succeeded", "running"):
        storage.job_dir(ids[status]).mkdir(parents=True)
        shutil.copy(results / "labelled.ply", storage.result_path(ids[status]))
    shutil.copy(results / "labelled.report.json", storage.report_path(ids["succeeded"]))

    source = ServiceSource(settings)
    try:
        listed = source.finished_jobs()
        assert {j.id for j in listed} == {ids["succeeded"], ids["gone"]}
        assert all(j.points == 4000 for j in listed)
        assert source.result_path(ids["succeeded"]) == storage.result_path(ids["succeeded"])
        assert source.report_path(ids["succeeded"]) == storage.report_path(ids["succeeded"])
        with pytest.raises(JobNotFound, match="running"):
            source.result_path(ids["running"])
        with pytest.raises(JobNotFound, match="gone"):
            source.result_path(ids["gone"])  # succeeded, but its files were deleted
        with pytest.raises(JobNotFound):
            source.result_path("../../etc/passwd")
        assert source.report_path("not-an-id") is None
    finally:
        source.close()
        engine.dispose()


def test_the_viewer_sees_what_its_key_sees_through_the_api(results: Path, tmp_path: Path) -> None:
    from server.api.auth import owner_of
    from server.settings import Settings
    from server.state.db import init_db, make_engine, make_sessions
    from server.state.jobs import create_job
    from server.state.models import Job
    from server.storage import Storage
    from web.serve import tenant_scope
    from web.service_source import ServiceSource

    settings = Settings(data_dir=tmp_path, api_keys=["key-one", "key-two"], admin_keys=["boss"])
    engine = make_engine(settings)
    init_db(engine)
    sessions, storage = make_sessions(engine), Storage(tmp_path)
    owners = {"one": owner_of("key-one"), "two": owner_of("key-two"), "old": None}
    ids = {name: uuid.uuid4().hex for name in owners}
    with sessions() as session:
        for name, job_id in ids.items():
            create_job(
                session,
                job_id=job_id,
                filename=f"{name}.ply",
                fmt="ply",
                size_bytes=1,
                points=4000,
                config={},
                network="randlanet",
                owner=owners[name],
            )
            row = session.get(Job, job_id)
            assert row is not None
            row.status = "succeeded"
            session.commit()
            storage.job_dir(job_id).mkdir(parents=True)
            shutil.copy(results / "labelled.ply", storage.result_path(job_id))
            shutil.copy(results / "labelled.report.json", storage.report_path(job_id))

    source = ServiceSource(settings)
    scope = tenant_scope(settings, source)
    try:
        one = scope("key-one")
        assert [j.id for j in one.finished_jobs()] == [ids["one"]]
        assert one.result_path(ids["one"]) == storage.result_path(ids["one"])
        for other in ("two", "old"):  # another key's job, a job from before tenants
            with pytest.raises(JobNotFound, match="not found"):
                one.result_path(ids[other])
            assert one.report_path(ids[other]) is None
        # a download goes through the API's own conversion, to the same tenant only
        assert one.export_path(ids["one"], "las") == storage.result_path(ids["one"], "las")
        assert storage.result_path(ids["one"], "las").is_file()
        with pytest.raises(JobNotFound, match="not found"):
            one.export_path(ids["two"], "las")
        assert not storage.result_path(ids["two"], "las").exists()
        assert {j.id for j in scope("boss").finished_jobs()} == set(ids.values())
        assert scope("boss").report_path(ids["two"]) == storage.report_path(ids["two"])
        with pytest.raises(AuthenticationError):  # a refused key sees nothing
            scope("key-three")
        open_scope = tenant_scope(Settings(data_dir=tmp_path), source)
        assert {j.id for j in open_scope(None).finished_jobs()} == set(ids.values())
    finally:
        source.close()
        engine.dispose()
