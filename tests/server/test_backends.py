"""The many-machines modes against this machine's servers: the job table and queue in
PostgreSQL (PostgresHuey: Huey's SQL storage), or the queue in Redis; an API without workers
and two separate `jointseg worker` processes, as on other machines sharing the data dir."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

from tests.support.service_process import REDIS, post_scan, running, scan_file, wait_for


def _run_jobs(service, scans, job_config, n: int = 4) -> list[dict]:
    with service.http() as http:

        def submit(seed: int) -> str:
            room = scan_file(scans, ".ply", seed=20 + seed, points=2000)
            response = post_scan(http, room, job_config)
            assert response.status_code == 201, response.text
            return str(response.json()["id"])

        with ThreadPoolExecutor(n) as pool:
            ids = list(pool.map(submit, range(n)))
        done = [wait_for(http, job_id, timeout=120) for job_id in ids]
        for job in done:
            assert http.get(f"/v1/jobs/{job['id']}/result").status_code == 200
    return done


def _run_everywhere(tmp_path, scans, job_config, kind: str, **settings: str) -> list[dict]:
    """An API without workers and two `jointseg worker` processes; four jobs through them."""
    with running(tmp_path / "shared", workers=0, extra_workers=2, **settings) as service:
        done = _run_jobs(service, scans, job_config)
        assert all(job["status"] == "succeeded" for job in done), done
        health = service.wait_healthy(workers=2)
        assert health["queue_kind"] == kind and health["pending"] == 0
    return done


def test_postgres_job_table_and_queue(tmp_path, scans, job_config, postgres_url) -> None:
    done = _run_everywhere(tmp_path, scans, job_config, "postgres", database_url=postgres_url)
    # the job table lives in PostgreSQL, not in the data directory
    assert not (tmp_path / "shared" / "jobs.sqlite3").exists()
    assert not (tmp_path / "shared" / "queue.sqlite3").exists()
    import psycopg2

    with psycopg2.connect(postgres_url) as conn, conn.cursor() as cur:
        cur.execute("SELECT count(*) FROM jobs WHERE status = 'succeeded'")
        assert cur.fetchone()[0] == len(done)
        cur.execute("SELECT count(DISTINCT worker) FROM jobs")
        assert cur.fetchone()[0] >= 1


def test_redis_queue(tmp_path, scans, job_config, redis_queue) -> None:
    settings = {"queue": "redis", "redis_url": REDIS, "queue_name": redis_queue}
    _run_everywhere(tmp_path, scans, job_config, "redis", **settings)
    assert not (tmp_path / "shared" / "queue.sqlite3").exists()
