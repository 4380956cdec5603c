"""One scan, many workers, with real processes: a scan above its config's ``tiles.max_points``
is planned, its tiles run by whichever workers are free and merged once. A worker SIGKILLed
mid-tile loses only that tile (PostgreSQL table and queue, two `jointseg worker` processes);
the fan-out gives the labels of the single-process tiled run; a cancel stops the tiles; the
job's progress and tile counts are visible while it runs (the embedded SQLite service)."""

from __future__ import annotations

import os
import re
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from jointseg.io import read_scan
from jointseg.pipeline import PipelineConfig, load_predictor, segment_file
from tests.support.service_process import (
    floor_file,
    fresh_database,
    post_scan,
    running,
    scan_file,
    wait_for,
)

#: A 120 k-point floor with cores of at most 40 k points: four tiles of about 2 s each (the
#: random network on one torch thread).
POINTS = 120_000
TILE_POINTS = 40_000


@pytest.fixture(scope="module")
def floor(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return floor_file(tmp_path_factory.mktemp("floor"), points=POINTS)


@pytest.fixture(scope="module")
def tiled_config(job_config: dict[str, Any]) -> dict[str, Any]:
    return {**job_config, "tiles": {"max_points": TILE_POINTS}}


@dataclass
class KilledRun:
    """A tiled job during which one of two workers was SIGKILLed while running a tile."""

    job: dict[str, Any]
    report: dict[str, Any]
    result: Path
    parts: list[tuple[str, int, str, int, str]]  # kind, tile, status, attempts, worker
    killed: str
    tile_folder: Path


def _running_tile(url: str, job_id: str, timeout: float = 120.0) -> tuple[str, int]:
    """The worker (``host:pid``) and index of a tile that is well under way (read from the
    job_tiles table, so the kill lands inside a tile, not between tasks)."""
    import psycopg2

    deadline = time.monotonic() + timeout
    with psycopg2.connect(url) as conn:
        conn.autocommit = True
        with conn.cursor() as cur:
            while time.monotonic() < deadline:
                cur.execute(
                    "SELECT worker, tile FROM job_tiles WHERE job_id = %s AND kind = 'tile' "
                    "AND status = 'running' AND progress BETWEEN 0.05 AND 0.6",
                    (job_id,),
                )
                row = cur.fetchone()
                if row is not None:
                    return str(row[0]), int(row[1])
                time.sleep(0.05)
    raise AssertionError(f"no tile of job {job_id} got going")


def _parts(url: str, job_id: str) -> list[tuple[str, int, str, int, str]]:
    import psycopg2

    with psycopg2.connect(url) as conn, conn.cursor() as cur:
        cur.execute(
            "SELECT kind, tile, status, attempts, worker FROM job_tiles WHERE job_id = %s "
            "ORDER BY kind, tile",
            (job_id,),
        )
        return [tuple(row) for row in cur.fetchall()]


@pytest.fixture(scope="module")
def killed_run(
    tmp_path_factory: pytest.TempPathFactory, floor: Path, tiled_config: dict[str, Any]
) -> KilledRun:
    data = tmp_path_factory.mktemp("pg-tiles")
    with (
        fresh_database() as url,
        running(data, workers=0, extra_workers=2, database_url=url) as service,
        service.http() as http,
    ):
        created = post_scan(http, floor, tiled_config)
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]
        worker, _ = _running_tile(url, job_id)
        os.kill(int(worker.rpartition(":")[2]), signal.SIGKILL)
        job = wait_for(http, job_id, timeout=300)
        report = http.get(f"/v1/jobs/{job_id}/report").json()
        parts = _parts(url, job_id)
    return KilledRun(
        job=job,
        report=report,
        result=data / "jobs" / job_id / "result.ply",
        parts=parts,
        killed=worker,
        tile_folder=data / "jobs" / job_id / "tiles",
    )


def test_a_worker_killed_mid_tile_loses_only_that_tile(killed_run: KilledRun) -> None:
    job = killed_run.job
    assert job["status"] == "succeeded", job
    tiles = killed_run.report["tiles"]["count"]
    assert tiles > 1
    assert job["tiles"] == {"total": tiles, "done": tiles, "running": 0}
    assert job["progress"] == 1.0 and job["stage"] == "done" and job["points"] == POINTS
    # the killed worker's tile ran again, on the other worker; every other part ran once
    again = [p for p in killed_run.parts if p[3] == 2]
    assert len(again) == 1 and again[0][0] == "tile", killed_run.parts
    assert again[0][4] != killed_run.killed
    assert all(p[2] == "done" for p in killed_run.parts)
    assert {p[0] for p in killed_run.parts} == {"plan", "tile", "merge"}
    # every point labelled
    result = read_scan(killed_run.result)
    assert len(result) == POINTS
    fused, segment = result.fields["fused_label"], result.fields["segment"]
    assert len(fused) == len(segment) == POINTS
    assert fused.min() >= 0 and fused.max() <= 12
    assert segment.min() >= 0
    assert killed_run.report["points"] == POINTS
    assert {"prepare", "tiles", "join", "fusion", "write", "total"} <= set(job["timings"])
    assert not killed_run.tile_folder.exists()  # removed when the job ended


def test_the_fan_out_labels_like_the_single_process_tiled_run(
    killed_run: KilledRun, floor: Path, tiled_config: dict[str, Any], tmp_path: Path
) -> None:
    config = PipelineConfig.model_validate(tiled_config)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the workers run it (JOINTSEG_TORCH_THREADS=1)
    try:
        alone = segment_file(
            floor,
            tmp_path / "alone.ply",
            config,
            predictor=load_predictor(config.network),
            max_points=10 * POINTS,
        )
    finally:
        torch.set_num_threads(threads)
    served = read_scan(killed_run.result)
    expected = read_scan(tmp_path / "alone.ply")
    assert killed_run.report["tiles"]["count"] == alone.tiles == alone.report["tiles"]["count"]
    for name in ("network_label", "segment", "fused_label", "fused_confidence"):
        np.testing.assert_array_equal(served.fields[name], expected.fields[name])
    np.testing.assert_array_equal(served.xyz, read_scan(floor).xyz)


def _observe(http: Any, job_id: str, timeout: float = 240.0) -> list[dict[str, Any]]:
    """Every state of the job seen by polling GET until it ends."""
    seen: list[dict[str, Any]] = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = http.get(f"/v1/jobs/{job_id}").json()
        seen.append(job)
        if job["status"] in ("succeeded", "failed", "cancelled"):
            return seen
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not end in {timeout} s: {seen[-1]}")


def test_progress_and_tile_counts_are_visible_while_it_runs(
    service, floor: Path, tiled_config: dict[str, Any], scans: Path, job_config: dict[str, Any]
) -> None:
    with service.http() as http:
        job_id = post_scan(http, floor, tiled_config).json()["id"]
        seen = _observe(http, job_id)
        small = wait_for(http, post_scan(http, scan_file(scans), job_config).json()["id"])
        listed = http.get("/v1/jobs", params={"limit": 5}).json()["items"]
    final = seen[-1]
    assert final["status"] == "succeeded", final
    total = final["tiles"]["total"]
    assert total > 1 and final["tiles"] == {"total": total, "done": total, "running": 0}
    during = [job for job in seen if job["tiles"] is not None and job["status"] == "running"]
    stages = {job["stage"] for job in during}
    assert all(re.fullmatch(rf"tiles \d+/{total}|join|fusion|write", s) for s in stages), stages
    assert any(f"tiles {done}/{total}" in stages for done in range(1, total)), stages
    assert any(job["tiles"]["running"] >= 1 for job in during)
    assert any(0 < job["tiles"]["done"] < total for job in during)
    progress = [job["progress"] for job in seen]
    assert progress == sorted(progress) and 0.1 <= max(p for p in progress if p < 1) < 1
    assert {j["id"]: j["tiles"] for j in listed}[job_id] == final["tiles"]
    assert small["status"] == "succeeded" and small["tiles"] is None  # untiled: as before
    assert not (service.data_dir / "jobs" / job_id / "tiles").exists()


def test_cancel_stops_every_tile(
    service, floor: Path, tiled_config: dict[str, Any], scans: Path, job_config: dict[str, Any]
) -> None:
    with service.http() as http:
        job_id = post_scan(http, floor, tiled_config).json()["id"]
        deadline = time.monotonic() + 120
        job = http.get(f"/v1/jobs/{job_id}").json()
        while not (job["tiles"] and job["tiles"]["running"] >= 1):
            assert time.monotonic() < deadline and job["status"] in ("queued", "running"), job
            time.sleep(0.05)
            job = http.get(f"/v1/jobs/{job_id}").json()
        assert (service.data_dir / "jobs" / job_id / "tiles").is_dir()
        cancelled_at = time.monotonic()
        assert http.delete(f"/v1/jobs/{job_id}").status_code == 202
        job = wait_for(http, job_id, timeout=60)
        stopped_in = time.monotonic() - cancelled_at
        # the workers are free again: a small job goes through
        small = wait_for(http, post_scan(http, scan_file(scans), job_config).json()["id"])
        report = http.get(f"/v1/jobs/{job_id}/report")
    assert job["status"] == "cancelled" and job["error"] == "cancelled by request", job
    assert job["tiles"]["running"] == 0 and job["tiles"]["done"] < job["tiles"]["total"]
    assert stopped_in < 10  # running tiles stop at their next cancel check, not at their end
    assert small["status"] == "succeeded"
    assert report.status_code == 409
    folder = service.data_dir / "jobs" / job_id
    assert not (folder / "tiles").exists() and not (folder / "result.ply").exists()
    log = service.api.text()
    assert not re.search(rf"job {job_id}.*internal error", log)
