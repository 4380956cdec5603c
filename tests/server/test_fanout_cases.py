"""The fan-out's other paths, with real worker processes: tiled jobs on the Redis queue, a
worker SIGTERMed inside a tile (its tile goes back to the queue, not lost), and a tile that
fails for good (its job fails naming the tile, and its tile folder goes)."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from jointseg.io import read_scan
from jointseg.pipeline import PipelineConfig, load_predictor, segment_file
from tests.support.service_process import (
    REDIS,
    floor_file,
    fresh_database,
    post_scan,
    running,
    spawn,
    wait_for,
)

#: every test here starts `jointseg serve` itself
pytestmark = pytest.mark.service

#: Half test_tiled_jobs.py's floor: 60 k points in three tiles of at most 20 k core points, a
#: few seconds each (the random network on one torch thread).
POINTS = 60_000
TILE_POINTS = 20_000

#: ``(kind, tile, status, attempts, worker, error)`` of a job's rows in ``job_tiles``.
Part = tuple[str, int, str, int, str | None, str | None]


@pytest.fixture(scope="module")
def floor(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return floor_file(tmp_path_factory.mktemp("floor"), points=POINTS)


@pytest.fixture(scope="module")
def tiled_config(job_config: dict[str, Any]) -> dict[str, Any]:
    return {**job_config, "tiles": {"max_points": TILE_POINTS}}


@dataclass(frozen=True)
class Alone:
    """The library's single-process tiled run of the floor: what every fan-out must give."""

    output: Path
    tiles: int | None


@pytest.fixture(scope="module")
def alone(
    tmp_path_factory: pytest.TempPathFactory, floor: Path, tiled_config: dict[str, Any]
) -> Alone:
    config = PipelineConfig.model_validate(tiled_config)
    output = tmp_path_factory.mktemp("alone") / "alone.ply"
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as the workers run it (JOINTSEG_TORCH_THREADS=1)
    try:
        done = segment_file(
            floor,
            output,
            config,
            predictor=load_predictor(config.network),
            max_points=10 * POINTS,
        )
    finally:
        torch.set_num_threads(threads)
    assert done.tiles is not None and done.tiles == done.report["tiles"]["count"] > 1
    return Alone(output, done.tiles)


def _sqlite_url(data_dir: Path) -> str:
    return f"sqlite:///{(data_dir / 'jobs.sqlite3').resolve()}"


def _query(url: str, sql: str, **params: Any) -> list[Any]:
    """The rows of ``sql`` in the job table at ``url`` (SQLite or PostgreSQL, through psycopg2
    as the service uses it)."""
    from sqlalchemy import create_engine, text

    if url.startswith("postgresql://"):
        url = "postgresql+psycopg2://" + url.removeprefix("postgresql://")
    engine = create_engine(url)
    try:
        with engine.connect() as conn:
            return list(conn.execute(text(sql), params).all())
    finally:
        engine.dispose()


def _parts(url: str, job_id: str) -> list[Part]:
    """The job's parts as the job table holds them."""
    rows = _query(
        url,
        "SELECT kind, tile, status, attempts, worker, error FROM job_tiles "
        "WHERE job_id = :job ORDER BY kind, tile",
        job=job_id,
    )
    return [(str(k), int(t), str(s), int(a), w, e) for k, t, s, a, w, e in rows]


def _progress(url: str, job_id: str, tile: int) -> float:
    rows = _query(
        url,
        "SELECT progress FROM job_tiles WHERE job_id = :job AND kind = 'tile' AND tile = :tile",
        job=job_id,
        tile=tile,
    )
    return float(rows[0][0] or 0.0) if rows else 0.0


def _until(
    url: str, job_id: str, found: Callable[[list[Part]], Any], what: str, timeout: float = 120.0
) -> Any:
    """Poll the job's parts until ``found(parts)`` is truthy; returns that value."""
    deadline = time.monotonic() + timeout
    parts: list[Part] = []
    while time.monotonic() < deadline:
        parts = _parts(url, job_id)
        value = found(parts)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"job {job_id}: never {what}: {parts}")


def _gone(path: Path, timeout: float = 10.0) -> bool:
    """Whether ``path`` is absent, or disappears within ``timeout`` seconds (the folder is
    removed just after the job row ends)."""
    deadline = time.monotonic() + timeout
    while path.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return not path.exists()


def _assert_like_alone(result: Path, report: dict[str, Any], alone: Alone, floor: Path) -> None:
    served, expected = read_scan(result), read_scan(alone.output)
    assert report["tiles"]["count"] == alone.tiles
    for name in ("network_label", "segment", "fused_label", "fused_confidence"):
        np.testing.assert_array_equal(served.fields[name], expected.fields[name])
    np.testing.assert_array_equal(served.xyz, read_scan(floor).xyz)


def _assert_all_done(job: dict[str, Any], parts: list[Part], folder: Path) -> None:
    assert job["status"] == "succeeded", job
    total = job["tiles"]["total"]
    assert total > 1 and job["tiles"] == {"total": total, "done": total, "running": 0}
    assert job["progress"] == 1.0 and job["stage"] == "done" and job["points"] == POINTS
    assert {p[0] for p in parts} == {"plan", "tile", "merge"}
    assert all(p[2] == "done" for p in parts), parts  # nothing left running or queued
    assert _gone(folder / "tiles")


def test_tiled_job_on_the_redis_queue(
    tmp_path: Path,
    floor: Path,
    tiled_config: dict[str, Any],
    redis_queue: str,
    alone: Alone,
) -> None:
    data = tmp_path / "shared"
    settings = {"queue": "redis", "redis_url": REDIS, "queue_name": redis_queue}
    with (
        running(data, workers=0, extra_workers=2, **settings) as service,
        service.http() as http,
    ):
        created = post_scan(http, floor, tiled_config)
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]
        job = wait_for(http, job_id, timeout=300)
        report = http.get(f"/v1/jobs/{job_id}/report").json()
        health = service.wait_healthy(workers=2)
        parts = _parts(_sqlite_url(data), job_id)
    assert health["queue_kind"] == "redis" and health["pending"] == 0
    assert not (data / "queue.sqlite3").exists()  # the queue lived in Redis
    _assert_all_done(job, parts, data / "jobs" / job_id)
    assert all(p[3] == 1 for p in parts), parts  # every part ran once
    # both workers took tiles (each dequeues one task at a time from the shared queue)
    assert len({p[4] for p in parts if p[0] == "tile"}) == 2, parts
    _assert_like_alone(data / "jobs" / job_id / "result.ply", report, alone, floor)


def test_a_worker_sigtermed_inside_a_tile_hands_it_back(
    tmp_path: Path, floor: Path, tiled_config: dict[str, Any], alone: Alone
) -> None:
    data = tmp_path / "shared"
    with (
        fresh_database() as url,
        running(data, workers=0, extra_workers=2, database_url=url) as service,
        service.http() as http,
    ):
        created = post_scan(http, floor, tiled_config)
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]

        def under_way(parts: list[Part]) -> tuple[str, int] | None:
            """A tile well under way (so the signal lands inside it, not between tasks)."""
            for kind, tile, status, _, worker, _ in parts:
                if kind == "tile" and status == "running" and worker:
                    progress = _progress(url, job_id, tile)
                    if 0.05 <= progress <= 0.6:
                        return worker, tile
            return None

        worker, tile = _until(url, job_id, under_way, "running a tile")
        pid = int(worker.rpartition(":")[2])
        victim = next(w for w in service.workers if w.popen.pid == pid)
        os.kill(pid, signal.SIGTERM)
        # a graceful stop: the tile stops at its next cancel check, the worker exits at once
        assert victim.popen.wait(timeout=30) == 0, victim.text()[-3000:]
        # a supervisor restarts it, as on any machine
        service.workers.append(spawn(["worker"], service.env, data / "worker-restarted.log"))
        job = wait_for(http, job_id, timeout=300)
        report = http.get(f"/v1/jobs/{job_id}/report").json()
        parts = _parts(url, job_id)
        health = service.wait_healthy(workers=2)
    # the stopped worker signed off (it is not waited for as a live one)
    assert worker not in {w["id"] for w in health["workers"]}, health
    log = victim.text()
    assert f"tile {tile + 1}/" in log and "worker stopping" in log and "re-queued" in log, log
    _assert_all_done(job, parts, data / "jobs" / job_id)
    # the interrupted tile was handed back without counting an attempt, and run by another
    # worker; nothing was left for the heartbeat reaper (which would count the attempt)
    again = next(p for p in parts if p[:2] == ("tile", tile))
    assert again[3] == 1 and again[4] != worker, parts
    assert all(p[3] == 1 for p in parts), parts
    _assert_like_alone(data / "jobs" / job_id / "result.ply", report, alone, floor)


def test_a_tile_that_fails_fails_the_job(
    tmp_path: Path, floor: Path, tiled_config: dict[str, Any]
) -> None:
    """One worker runs the tiles in order; while it runs the first, the second tile's list of
    points is removed from the work folder: loading that tile raises a real error."""
    data = tmp_path / "single"
    url = _sqlite_url(data)
    with running(data, workers=1) as service, service.http() as http:
        created = post_scan(http, floor, tiled_config)
        assert created.status_code == 201, created.text
        job_id = created.json()["id"]

        def planned(parts: list[Part]) -> list[Part]:
            return [p for p in parts if p[0] == "tile"]

        tile_rows = _until(url, job_id, planned, "planned")
        total = len(tile_rows)
        assert total >= 3 and tile_rows[1][2] == "queued", tile_rows
        work = data / "jobs" / job_id / "tiles"
        (index,) = work.glob("*/tiles/0001/index.i64")
        index.unlink()
        job = wait_for(http, job_id, timeout=300)
        report = http.get(f"/v1/jobs/{job_id}/report")
        parts = _parts(url, job_id)
    assert job["status"] == "failed" and job["stage"] == "failed", job
    error = job["error"]
    assert error.startswith(f"tile 2/{total} (job_tiles.tile 1) failed: "), error
    assert error.endswith("tiles/0001/index.i64: tile index missing (folder not prepared?)"), error
    assert str(data) not in error  # no server path: "<tile folder>/tiles/0001/..."
    assert job["tiles"] == {"total": total, "done": 1, "running": 0}, job
    assert report.status_code == 409
    by = {(p[0], p[1]): p for p in parts}
    assert by[("tile", 0)][2] == "done", parts
    assert by[("tile", 1)][2:4] == ("failed", 1) and by[("tile", 1)][5] == error, parts
    # the tiles after it and the merge never ran, and nothing is left running
    assert all(by[("tile", i)][2] == "cancelled" for i in range(2, total)), parts
    assert by[("merge", 0)][2] == "cancelled", parts
    assert _gone(work)
    assert not (data / "jobs" / job_id / "result.ply").exists()
