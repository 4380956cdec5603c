"""Models learnt from an owner's corrections through the real service (issue 66, point 2):
``POST /v1/models`` over a job corrected with ``PATCH .../labels`` reaches succeeded with its
card naming the job and version, a later job runs with ``network.weights: "model:<id>"``;
another key gets 404 and cannot use it; bad requests name the field and create nothing; a
worker killed mid-model is requeued and the model finishes, on PostgreSQL, and survives a
restart."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.support.service_process import (
    FINAL,
    Service,
    post_scan,
    running,
    scan_file,
    wait_for,
)

#: every test here starts `jointseg serve` (or uses a started one)
pytestmark = pytest.mark.service

POINTS = 20_000
#: A model that learns in a few seconds: few steps, no generated rooms.
QUICK = {"steps": 20, "replay_rooms": 0}


def _client(service: Service, key: str) -> httpx.Client:
    headers = {"Authorization": f"Bearer {key}"}
    return httpx.Client(base_url=service.url, headers=headers, timeout=60)


@pytest.fixture(scope="module")
def two_keys(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """A service with two tenants' keys and one worker (SQLite table and queue)."""
    folder = tmp_path_factory.mktemp("models")
    with running(folder, workers=1, api_keys="key-one,key-two") as svc:
        yield svc


def _finished_job(http: httpx.Client, scans: Path, config: dict[str, Any], seed: int) -> str:
    source = scan_file(scans, ".ply", points=POINTS, seed=seed)
    created = post_scan(http, source, {**config, "quality": "fast"}, filename="office.ply")
    assert created.status_code == 201, created.text
    job_id = str(created.json()["id"])
    assert wait_for(http, job_id, timeout=240)["status"] == "succeeded"
    return job_id


def _corrected_job(http: httpx.Client, scans: Path, config: dict[str, Any], seed: int) -> str:
    """A succeeded job whose first 3 000 points a user called beams (labels version 1)."""
    job_id = _finished_job(http, scans, config, seed)
    edits = {"edits": [{"points": list(range(3000)), "label": "beam"}]}
    done = http.patch(f"/v1/jobs/{job_id}/labels", json=edits, headers={"If-Match": '"v0"'})
    assert done.status_code == 200, done.text
    return job_id


def _wait_model(
    http: httpx.Client, model_id: str, timeout: float = 240, until: tuple[str, ...] = FINAL
) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    model: dict[str, Any] = {}
    while time.monotonic() < deadline:
        model = http.get(f"/v1/models/{model_id}").json()
        if model["status"] in until:
            return model
        time.sleep(0.2)
    raise AssertionError(f"model {model_id} not {until} in {timeout} s: {model}")


def _refused(answer: httpx.Response, status: int, detail: str) -> None:
    assert answer.status_code == status, answer.text
    assert detail in answer.json()["detail"], answer.text


def test_a_model_learns_from_corrections_and_a_later_job_uses_it(
    two_keys: Service, scans: Path, job_config: dict[str, Any], tmp_path: Path
) -> None:
    from jointseg.network.randlanet.checkpoint import load_checkpoint

    with _client(two_keys, "key-one") as one, _client(two_keys, "key-two") as two:
        job_id = _corrected_job(one, scans, job_config, seed=51)
        body = {"jobs": [job_id], "name": "site A", "params": QUICK}
        made = one.post("/v1/models", json=body)
        assert made.status_code == 201, made.text
        model_id = made.json()["id"]
        assert made.headers["location"] == f"/v1/models/{model_id}"
        assert made.json()["sources"] == [{"job_id": job_id, "version": 1}]
        model = _wait_model(one, model_id)
        assert model["status"] == "succeeded" and model["progress"] == 1.0, model
        assert model["weights"] == f"model:{model_id}" and model["name"] == "site A"
        scans_seen = model["adapted"]["scans"]
        assert [(s["name"], s["version"]) for s in scans_seen] == [(job_id, 1)]
        assert model["adapted"]["corrected_points"] == 3000
        assert model["adapted"]["params"]["steps"] == 20
        listed = one.get("/v1/models").json()
        assert [m["id"] for m in listed["items"]] == [model_id] and listed["total"] == 1
        # a model is no job: not in the jobs' list, 404 as a job
        assert model_id not in [j["id"] for j in one.get("/v1/jobs").json()["items"]]
        assert one.get(f"/v1/jobs/{model_id}").status_code == 404
        got = one.get(f"/v1/models/{model_id}/file")
        assert (
            got.status_code == 200 and 'filename="site_A.pt"' in got.headers["content-disposition"]
        )
        (tmp_path / "m.pt").write_bytes(got.content)
        assert load_checkpoint(tmp_path / "m.pt")[1]["adapted"]["scans"][0]["name"] == job_id

        weights = {"network": {"weights": f"model:{model_id}", "device": "cpu"}}
        later = post_scan(one, scan_file(scans, ".ply", points=POINTS, seed=52), weights)
        assert later.status_code == 201, later.text
        assert wait_for(one, later.json()["id"], timeout=240)["status"] == "succeeded"
        report = one.get(f"/v1/jobs/{later.json()['id']}/report").json()
        assert report["params"]["network"]["weights"] == f"model:{model_id}"

        _other_keys_get_404(two, one, model_id, job_id, scans)
        _client_lists_downloads_and_deletes(two_keys, model_id, tmp_path)
        assert not (two_keys.data_dir / "jobs" / model_id).exists()
        assert one.get(f"/v1/models/{model_id}").status_code == 404
        gone = post_scan(one, scan_file(scans, ".ply", points=1000, seed=53), weights)
        _refused(gone, 422, "config.network.weights")


def _client_lists_downloads_and_deletes(service: Service, model_id: str, folder: Path) -> None:
    """``JobClient``'s models: listed, read, downloaded, deleted (then 404)."""
    from jointseg.client import JobClient
    from jointseg.exceptions import ServiceError

    with JobClient(service.url, api_key="key-one") as client:
        assert [m["id"] for m in client.models()] == [model_id]
        assert client.model(model_id)["status"] == "succeeded"
        assert client.download_model(model_id, folder / "c.pt").stat().st_size > 0
        assert client.delete_model(model_id) is None
        with pytest.raises(ServiceError) as gone:
            client.model(model_id)
        assert gone.value.status_code == 404


def _other_keys_get_404(
    two: httpx.Client, one: httpx.Client, model_id: str, job_id: str, scans: Path
) -> None:
    """Another key: 404 on the model, its file and its delete; it is not listed, cannot be
    used in ``network.weights`` and the owner's job cannot teach the other key a model."""
    for answer in (
        two.get(f"/v1/models/{model_id}"),
        two.get(f"/v1/models/{model_id}/file"),
        two.delete(f"/v1/models/{model_id}"),
    ):
        _refused(answer, 404, f"model {model_id} not found")
    assert two.get("/v1/models").json()["total"] == 0
    weights = {"network": {"weights": f"model:{model_id}"}}
    used = post_scan(two, scan_file(scans, ".ply", points=1000, seed=53), weights)
    _refused(used, 422, "config.network.weights: no model")
    _refused(two.post("/v1/models", json={"jobs": [job_id]}), 404, "jobs[0]")
    assert one.get(f"/v1/models/{model_id}").json()["status"] == "succeeded"  # untouched


def test_an_uncorrected_job_teaches_nothing(
    two_keys: Service, scans: Path, job_config: dict[str, Any]
) -> None:
    with _client(two_keys, "key-two") as two:
        plain = _finished_job(two, scans, job_config, seed=54)
        _refused(two.post("/v1/models", json={"jobs": [plain]}), 422, "jobs[0]: no corrected")
        twice = two.post("/v1/models", json={"jobs": [plain, plain]})
        _refused(twice, 422, "jobs[1]")
        assert two.get("/v1/models").json()["total"] == 0


def test_bad_model_requests_name_the_field_and_create_nothing(locked: Service, scans: Path) -> None:
    with _client(locked, "key-one") as one:
        # the service is shared with other tests: compare with what it held before
        models_before = one.get("/v1/models").json()["total"]
        jobs_before = one.get("/v1/jobs").json()["total"]
        queued = post_scan(one, scan_file(scans, ".ply", points=1000, seed=55))
        assert queued.status_code == 201, queued.text  # no worker: it stays queued
        queued_id = queued.json()["id"]
        unknown = "0" * 32
        for body, status, detail in (
            ({"jobs": []}, 422, "body.jobs"),
            ({}, 422, "body.jobs"),
            ({"jobs": [unknown]}, 404, f"jobs[0]: job {unknown} not found"),
            ({"jobs": ["../etc"]}, 404, "jobs[0]"),
            ({"jobs": [queued_id]}, 409, "jobs[0]"),
            ({"jobs": [queued_id], "params": {"steps": 0}}, 422, "body.params.steps"),
            (
                {"jobs": [queued_id], "params": {"min_base_probability": 1.5}},
                422,
                "body.params.min_base_probability",
            ),
            ({"jobs": [queued_id], "colour": True}, 422, "body.colour"),
        ):
            _refused(one.post("/v1/models", json=body), status, detail)
        jobs_after = one.get("/v1/jobs").json()
        assert one.get("/v1/models").json()["total"] == models_before
        assert queued_id in [j["id"] for j in jobs_after["items"]]
        assert jobs_before + 1 == jobs_after["total"]  # no job made by a refused request
        assert not (locked.data_dir / "jobs" / queued_id / "model.pt").exists()


def test_sigkill_mid_model_is_requeued_and_the_model_survives_a_restart(
    tmp_path: Path, scans: Path, job_config: dict[str, Any], postgres_url: str
) -> None:
    folder = tmp_path / "svc"
    settings: dict[str, Any] = {"database_url": postgres_url, "heartbeat_timeout_s": 60}
    with running(folder, workers=1, **settings) as svc, svc.http() as http:
        job_id = _corrected_job(http, scans, job_config, seed=56)
        body = {"jobs": [job_id], "params": {"steps": 800, "replay_rooms": 0}}
        model_id = http.post("/v1/models", json=body).json()["id"]
        deadline = time.monotonic() + 120
        while True:  # learning: the head's fit under way
            model = http.get(f"/v1/models/{model_id}").json()
            assert model["status"] in ("queued", "running"), model
            if model["stage"] == "adapt" and model["progress"] > 0.45:
                break
            assert time.monotonic() < deadline, model
            time.sleep(0.1)
        workers = svc.wait_healthy()["workers"]
        pid = next(int(w["pid"]) for w in workers if w["job_id"] == model_id)
        os.kill(pid, signal.SIGKILL)
        model = _wait_model(http, model_id)
        assert model["status"] == "succeeded" and model["attempts"] == 2, model
        assert "died" in svc.api.text()
    with running(folder, workers=0, **settings) as svc, svc.http() as http:
        again = http.get(f"/v1/models/{model_id}").json()
        assert again["status"] == "succeeded" and again["adapted"] == model["adapted"]
        assert http.get(f"/v1/models/{model_id}/file").status_code == 200
