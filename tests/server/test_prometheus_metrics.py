"""``GET /metrics`` (issue 68, point 2) read by prometheus-client's own parser from a real
service (uvicorn, one worker process, the embedded SQLite table): every series is there, and
the values move when a job runs, fails and an upload arrives. Locked services: admin keys
only."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest
import torch

from tests.support.service_process import post_scan, running, scan_file, wait_for

pytestmark = pytest.mark.service
parser = pytest.importorskip("prometheus_client.parser")

SERIES = {
    "jointseg_jobs": "gauge",
    "jointseg_queue_depth": "gauge",
    "jointseg_live_workers": "gauge",
    "jointseg_job_duration_seconds": "histogram",
    "jointseg_stage_duration_seconds": "histogram",
    "jointseg_jobs_finished": "counter",
    "jointseg_job_failures": "counter",
    "jointseg_uploads": "counter",
    "jointseg_upload_bytes": "counter",
}


def _scrape(http: httpx.Client) -> dict[str, Any]:
    answer = http.get("/metrics")
    assert answer.status_code == 200, answer.text
    assert answer.headers["content-type"].startswith("text/plain")
    families = {f.name: f for f in parser.text_string_to_metric_families(answer.text)}
    values: dict[tuple[str, tuple[tuple[str, str], ...]], float] = {}
    for family in families.values():
        for sample in family.samples:
            values[(sample.name, tuple(sorted(sample.labels.items())))] = sample.value
    return {"families": families, "values": values}


def _value(scrape: dict[str, Any], name: str, **labels: str) -> float:
    return scrape["values"].get((name, tuple(sorted(labels.items()))), 0.0)


def _histogram_count(scrape: dict[str, Any], name: str, **labels: str) -> float:
    """The count of a histogram summed over the label sets that include ``labels``."""
    return sum(
        v
        for (n, ls), v in scrape["values"].items()
        if n == f"{name}_count" and set(labels.items()) <= set(ls)
    )


def test_metrics_move_when_jobs_run_fail_and_uploads_arrive(
    tmp_path: Path, scans: Path, job_config: dict[str, Any]
) -> None:
    room = scan_file(scans, ".ply", points=3000, seed=3)
    with running(tmp_path / "data", workers=1) as service, service.http() as http:
        before = _scrape(http)
        assert _value(before, "jointseg_live_workers") == 1
        job = wait_for(http, post_scan(http, room, job_config).json()["id"])
        assert job["status"] == "succeeded", job
        failed = None
        if not torch.cuda.is_available():  # a job that fails in the worker
            config = {**job_config, "network": {**job_config["network"], "device": "cuda"}}
            failed = wait_for(http, post_scan(http, room, config).json()["id"])
            assert failed["status"] == "failed", failed
        after = _scrape(http)
    runs = 2 if failed else 1
    assert (
        _value(after, "jointseg_uploads_total") - _value(before, "jointseg_uploads_total") == runs
    )
    grown = _value(after, "jointseg_upload_bytes_total") - _value(
        before, "jointseg_upload_bytes_total"
    )
    assert grown == runs * room.stat().st_size
    assert (
        _value(after, "jointseg_jobs", status="succeeded")
        == _value(before, "jointseg_jobs", status="succeeded") + 1
    )
    assert _value(after, "jointseg_jobs_finished_total", status="succeeded") >= 1
    count = _histogram_count(after, "jointseg_job_duration_seconds", status="succeeded")
    assert (
        count == _histogram_count(before, "jointseg_job_duration_seconds", status="succeeded") + 1
    )
    # the job's stages, each observed once
    for stage in ("network", "geometry", "fusion", "write"):
        assert _histogram_count(after, "jointseg_stage_duration_seconds", stage=stage) >= 1, stage
    total = _value(after, "jointseg_job_duration_seconds_sum", kind="scan", status="succeeded")
    assert (
        0
        < total
        <= job["timings"]["total"]
        + 1e-3
        + _value(before, "jointseg_job_duration_seconds_sum", kind="scan", status="succeeded")
    )
    assert _value(after, "jointseg_queue_depth", kind="job") == 0
    if failed:
        failures = {
            dict(ls)["error"]: v
            for (n, ls), v in after["values"].items()
            if n == "jointseg_job_failures_total"
        }
        assert sum(failures.values()) == 1 and list(failures) != ["unknown"], failures
        assert _value(after, "jointseg_jobs", status="failed") == 1


def test_a_locked_services_metrics_need_an_admin_key(locked) -> None:
    with httpx.Client(base_url=locked.url, timeout=30) as http:
        assert http.get("/metrics").status_code == 401
        ordinary = http.get("/metrics", headers={"Authorization": "Bearer key-one"})
        assert ordinary.status_code == 403 and ordinary.json()["error"], ordinary.text
        admin = http.get("/metrics", headers={"Authorization": "Bearer key-admin"})
        assert admin.status_code == 200 and "jointseg_jobs" in admin.text
