"""Versioned labels and reruns through the real service (uvicorn + workers): a correction is a
new version with its own ETag and downloads, refusals (428, 412, 422, another key's 404) write
nothing, versions survive a restart on SQLite and PostgreSQL, and a rerun is a new job from
the same upload with another frame."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX
from jointseg.io import read_scan
from tests.support.service_process import Service, post_scan, running, scan_file, wait_for

POINTS = 20_000


def _finished_job(http: httpx.Client, scans: Path, config: dict[str, Any], seed: int) -> str:
    """A succeeded job of a small synthetic room, run at the fast quality."""
    source = scan_file(scans, ".ply", points=POINTS, seed=seed)
    created = post_scan(http, source, {**config, "quality": "fast"}, filename="office.ply")
    assert created.status_code == 201, created.text
    job_id = str(created.json()["id"])
    assert wait_for(http, job_id, timeout=240)["status"] == "succeeded"
    return job_id


def _scan(response: httpx.Response, folder: Path, name: str) -> Any:
    assert response.status_code == 200, response.text
    path = folder / name
    path.write_bytes(response.content)
    return read_scan(path)


def _npy_files(data_dir: Path, job_id: str) -> list[str]:
    folder = data_dir / "jobs" / job_id / "labels"
    return sorted(p.name for p in folder.glob("*.npy")) if folder.exists() else []


def _refused(http: httpx.Client, url: str, body: Any, status: int, detail: str, **kw: Any) -> None:
    headers = {"If-Match": '"v0"', **kw.pop("headers", {})}
    content = body if isinstance(body, bytes) else json.dumps(body).encode()
    answer = http.patch(url, content=content, headers=headers)
    assert answer.status_code == status, answer.text
    assert detail in answer.json()["detail"], answer.text


def test_a_correction_is_a_new_version_with_its_own_downloads(
    service: Service, scans: Path, job_config: dict[str, Any], tmp_path: Path
) -> None:
    with service.http() as http:
        job_id = _finished_job(http, scans, job_config, seed=41)
        url = f"/v1/jobs/{job_id}/labels"
        first = http.get(url)
        assert first.status_code == 200 and first.headers["etag"] == '"v0"'
        job = http.get(f"/v1/jobs/{job_id}").json()
        assert first.json()["history"] == [
            {
                "version": 0,
                "created_at": job["finished_at"],
                "owner": None,
                "points_changed": 0,
                "points_corrected": 0,
                "edits": 0,
            }
        ]
        before = http.get(f"/v1/jobs/{job_id}/result")
        machine = _scan(before, tmp_path, "v0.ply")
        fused = np.asarray(machine.fields["fused_label"])
        segment = np.asarray(machine.fields["segment"])

        good = {"edits": [{"segments": [int(segment[0])], "label": "board"}]}
        good["edits"].append({"points": [1, 2, 3], "label": CLASS_INDEX["sofa"]})
        no_tag = http.patch(url, json=good)
        assert no_tag.status_code == 428, no_tag.text
        _refused(http, url, good, 412, "not the current", headers={"If-Match": '"v3"'})
        _refused(http, url, {"edits": [{"points": [0], "label": "wal"}]}, 422, "edits[0].label")
        too_far = int(segment.max()) + 1
        _refused(
            http, url, {"edits": [{"segments": [too_far], "label": 1}]}, 422, "edits[0].segments"
        )
        _refused(http, url, {"edits": [{"points": [POINTS], "label": 1}]}, 422, "edits[0].points")
        box = {"min": [1, 0, 0], "max": [0, 1, 1]}
        _refused(http, url, {"edits": [{"box": box, "label": 1}]}, 422, "edits[0].box")
        _refused(http, url, b"{not json", 422, "body: not valid JSON")
        _refused(http, url, {"edits": []}, 422, "edits")
        assert http.get(url).json()["version"] == 0
        assert _npy_files(service.data_dir, job_id) == []  # nothing written on any refusal

        done = http.patch(url, json=good, headers={"If-Match": '"v0"'})
        assert done.status_code == 200, done.text
        assert done.headers["etag"] == '"v1"' and done.json()["version"] == 1
        entry = done.json()["history"][1]
        assert entry["version"] == 1 and entry["edits"] == 2
        assert entry["owner"] is not None and entry["points_corrected"] > 0
        assert http.get(url).headers["etag"] == '"v1"'
        assert http.get(f"/v1/jobs/{job_id}").json()["labels_version"] == 1
        assert _npy_files(service.data_dir, job_id) == ["v1.npy"]

        # version 0 is the run's own file, byte for byte; the default is the current version
        assert http.get(f"/v1/jobs/{job_id}/result", params={"version": 0}).content == (
            before.content
        )
        latest = http.get(f"/v1/jobs/{job_id}/result")
        assert 'filename="office_segmented_v1.ply"' in latest.headers["content-disposition"]
        corrected = _scan(latest, tmp_path, "v1.ply")
        wanted = fused.copy()
        wanted[segment == segment[0]] = CLASS_INDEX["board"]
        wanted[[1, 2, 3]] = CLASS_INDEX["sofa"]
        assert np.array_equal(corrected.fields["fused_label"], wanted)
        user = np.asarray(corrected.fields["user_label"])
        assert set(np.flatnonzero(user >= 0)) == set(np.flatnonzero(segment == segment[0])) | {
            1,
            2,
            3,
        }
        _check_las(http, job_id, user, wanted, tmp_path)
        report = http.get(f"/v1/jobs/{job_id}/report", params={"version": 1}).json()
        assert report["labels"] == {"version": 1, "points_corrected": entry["points_corrected"]}
        assert "labels" not in http.get(f"/v1/jobs/{job_id}/report", params={"version": 0}).json()
        objects = [
            http.get(f"/v1/jobs/{job_id}/objects", params={"version": v}).status_code
            for v in (0, 1)
        ]
        assert objects[0] == objects[1] and objects[0] in (200, 409)
        missing = http.get(f"/v1/jobs/{job_id}/result", params={"version": 2})
        assert missing.status_code == 404 and "versions are 0 to 1" in missing.json()["detail"]
        _refused(http, url, good, 412, "not the current")  # "v0" is stale now
    _client_builds_on_the_current_version(service, job_id, segment, tmp_path)


def _client_builds_on_the_current_version(
    service: Service, job_id: str, segment: np.ndarray, folder: Path
) -> None:
    """``JobClient.correct`` reads the current ETag and saves over it; a stale one is 412;
    ``download(version=0)`` is still the machine's own labels."""
    from jointseg.client import JobClient
    from jointseg.exceptions import ServiceError

    with JobClient(service.url, api_key=service.api_key) as client:
        edits = [{"segments": [int(segment[0])], "label": "wall"}]
        state, tag = client.correct(job_id, edits)
        assert state["version"] == 2 and tag == '"v2"'
        with pytest.raises(ServiceError) as stale:
            client.correct(job_id, edits, etag='"v1"')
        assert stale.value.status_code == 412
        assert client.labels(job_id)[0]["version"] == 2
        latest = read_scan(client.download(job_id, folder / "v2.laz"))
        first = read_scan(client.download(job_id, folder / "v0.laz", version=0))
    inside = segment == segment[0]
    assert (np.asarray(latest.fields["fused_label"])[inside] == CLASS_INDEX["wall"]).all()
    assert "user_label" not in first.fields


def _check_las(
    http: httpx.Client, job_id: str, user: np.ndarray, labels: np.ndarray, folder: Path
) -> None:
    """The version's LAS: classification 64 + the version's class (the user's where given),
    and a ``user_label``."""
    import laspy

    answer = http.get(f"/v1/jobs/{job_id}/result", params={"format": "las", "version": 1})
    assert answer.status_code == 200, answer.text
    assert 'filename="office_segmented_v1.las"' in answer.headers["content-disposition"]
    (folder / "v1.las").write_bytes(answer.content)
    las = laspy.read(folder / "v1.las")
    classes = np.asarray(las.classification)
    mine = user >= 0
    assert np.array_equal(classes[mine], 64 + user[mine])
    assert np.array_equal(classes, 64 + labels)  # a result's classes: 64 + the version's
    assert np.array_equal(np.asarray(las["user_label"]), user)


def test_a_rerun_is_a_new_job_with_the_frame_over_the_old_config(
    service: Service, scans: Path, job_config: dict[str, Any]
) -> None:
    with service.http() as http:
        old = _finished_job(http, scans, job_config, seed=42)
        url = f"/v1/jobs/{old}/rerun"
        bad = http.post(url, json={"frame": {"up": "sideways"}})
        assert bad.status_code == 422 and "frame.up" in bad.json()["detail"], bad.text
        extra = http.post(url, json={"frame": {"seed": 3}})
        assert extra.status_code == 422 and "frame.seed" in extra.json()["detail"], extra.text
        made = http.post(url, json={"frame": {"up": "+y", "level": False}})
        assert made.status_code == 201, made.text
        new = made.json()
        assert made.headers["location"] == f"/v1/jobs/{new['id']}"
        assert new["rerun_of"] == old and new["id"] != old and new["filename"] == "office.ply"
        jobs_dir = service.data_dir / "jobs"
        assert (jobs_dir / new["id"] / "input.ply").stat().st_ino == (
            (jobs_dir / old / "input.ply").stat().st_ino
        )  # the same upload, linked
        table = sqlite3.connect(service.data_dir / "jobs.sqlite3")
        try:
            rows = dict(
                table.execute("SELECT id, config FROM jobs WHERE id IN (?, ?)", (old, new["id"]))
            )
        finally:
            table.close()
        before, after = json.loads(rows[old]), json.loads(rows[new["id"]])
        assert after["frame"] == {**before["frame"], "up": "+y", "level": False}
        assert {k: v for k, v in after.items() if k != "frame"} == {
            k: v for k, v in before.items() if k != "frame"
        }
        assert wait_for(http, new["id"], timeout=240)["status"] == "succeeded"
        frame = http.get(f"/v1/jobs/{new['id']}/report").json()["frame"]
        assert frame["up"]["axis"] == "+y" and not frame["up"]["levelled"]  # as told
        kept = http.get(f"/v1/jobs/{old}").json()
        assert kept["status"] == "succeeded" and kept["rerun_of"] is None
        assert http.get(f"/v1/jobs/{old}/labels").json()["version"] == 0


def _client(service: Service, key: str) -> httpx.Client:
    return httpx.Client(
        base_url=service.url, headers={"Authorization": f"Bearer {key}"}, timeout=60
    )


@pytest.mark.service
@pytest.mark.parametrize("backend", ["sqlite", "postgres"])
def test_versions_are_the_owners_and_survive_a_restart(
    backend: str,
    tmp_path: Path,
    scans: Path,
    job_config: dict[str, Any],
    request: pytest.FixtureRequest,
) -> None:
    settings: dict[str, Any] = {"api_keys": "key-one,key-two"}
    if backend == "postgres":
        settings["database_url"] = request.getfixturevalue("postgres_url")
    folder = tmp_path / "data"
    with running(folder, workers=1, **settings) as svc:
        with _client(svc, "key-one") as one, _client(svc, "key-two") as two:
            job_id = _finished_job(one, scans, job_config, seed=43)
            url = f"/v1/jobs/{job_id}/labels"
            edits = {"edits": [{"points": [0, 5], "label": "door"}]}
            for answer in (
                two.get(url),
                two.patch(url, json=edits, headers={"If-Match": '"v0"'}),
                two.get(f"/v1/jobs/{job_id}/result", params={"version": 0}),
                two.post(f"/v1/jobs/{job_id}/rerun", json={"frame": {"up": "+z"}}),
            ):
                assert answer.status_code == 404, answer.text
            assert _npy_files(folder, job_id) == []
            done = one.patch(url, json=edits, headers={"If-Match": '"v0"'})
            assert done.status_code == 200, done.text
            history = done.json()["history"]
    with running(folder, workers=0, **settings) as svc, _client(svc, "key-one") as one:
        again = one.get(url)
        assert again.status_code == 200 and again.headers["etag"] == '"v1"'
        assert again.json()["history"] == history
        assert one.get(f"/v1/jobs/{job_id}/result", params={"version": 1}).status_code == 200
        assert one.delete(f"/v1/jobs/{job_id}").status_code == 204
        assert not (folder / "jobs" / job_id).exists()
        assert one.get(url).status_code == 404
    _assert_no_version_rows(folder, settings.get("database_url"))


def _assert_no_version_rows(folder: Path, url: str | None) -> None:
    """A deleted job's version rows are gone from the table."""
    from sqlalchemy import create_engine, text

    address = url.replace("postgresql://", "postgresql+psycopg2://") if url else None
    engine = create_engine(address or f"sqlite:///{folder / 'jobs.sqlite3'}")
    try:
        with engine.connect() as conn:
            assert conn.execute(text("SELECT count(*) FROM label_versions")).scalar() == 0
    finally:
        engine.dispose()
