"""Job routes beyond the round trip: cancel (queued and running), delete, list and filter,
results of unfinished jobs, health."""

from __future__ import annotations

import time

from tests.support.service_process import post_scan, scan_file, wait_for


def test_cancel_a_running_job_stops_it_within_seconds(service, scans, job_config) -> None:
    with service.http() as http:
        # big enough that the job is still in its network stage when the DELETE arrives
        job_id = post_scan(http, scan_file(scans, ".ply", points=300_000, seed=6), job_config)
        job_id = job_id.json()["id"]
        wait_for(http, job_id, until=("running",), stage="network", timeout=60)
        asked = time.monotonic()
        response = http.delete(f"/v1/jobs/{job_id}")
        assert response.status_code == 202 and response.json()["status"] == "running"
        job = wait_for(http, job_id, timeout=30)
        took = time.monotonic() - asked
        assert job["status"] == "cancelled" and job["error"] == "cancelled by request"
        assert took < 5, f"cancel took {took:.1f} s"
        assert http.get(f"/v1/jobs/{job_id}/result").status_code == 409
        assert not (service.data_dir / "jobs" / job_id / "result.ply").exists()
        # a second DELETE removes the finished job and its files
        assert http.delete(f"/v1/jobs/{job_id}").status_code == 204
        assert http.get(f"/v1/jobs/{job_id}").status_code == 404
        assert not (service.data_dir / "jobs" / job_id).exists()


def test_cancel_queued_jobs_list_and_filter(locked, scans) -> None:
    room = scan_file(scans, ".ply", points=1000, seed=8)
    with locked.http() as http:  # no worker: jobs stay queued
        ids = [post_scan(http, room).json()["id"] for _ in range(3)]
        cancelled = http.delete(f"/v1/jobs/{ids[0]}")
        assert cancelled.status_code == 202 and cancelled.json()["status"] == "cancelled"
        assert http.get(f"/v1/jobs/{ids[0]}/result").status_code == 409
        assert http.get(f"/v1/jobs/{ids[1]}/report").status_code == 409
        queued = http.get("/v1/jobs", params={"status": "queued"}).json()
        assert {ids[1], ids[2]} <= {j["id"] for j in queued["items"]}
        assert ids[0] not in {j["id"] for j in queued["items"]}
        page = http.get("/v1/jobs", params={"limit": 2, "offset": 0}).json()
        assert [j["id"] for j in page["items"]] == [ids[2], ids[1]]  # newest first
        assert page["total"] >= 3 and page["limit"] == 2
        second = http.get("/v1/jobs", params={"limit": 2, "offset": 2}).json()
        assert second["items"][0]["id"] == ids[0]
        for job_id in ids[1:]:
            assert http.delete(f"/v1/jobs/{job_id}").status_code == 202
        health = http.get("/healthz").json()
    assert health["status"] == "degraded" and health["workers"] == []  # up, but no worker
    assert health["database"] and health["queue"] and health["queue_kind"] == "sqlite"


def test_health_reports_both_workers(service) -> None:
    health = service.wait_healthy(workers=2)
    assert health["status"] == "ok" and len({w["pid"] for w in health["workers"]}) == 2
