"""Tenants: each API key sees and manages only the jobs it submitted, another key's job is the
same 404 as a job that does not exist, admin keys see every job; the owner is stored as a hash
of the key, and job tables from before the owner column are migrated (SQLite and PostgreSQL)."""

from __future__ import annotations

import sqlite3
import uuid
from pathlib import Path
from typing import Any

import httpx
import pytest
from sqlalchemy import Column, MetaData, Table, inspect, text

from jointseg.exceptions import JobNotFound
from server.api.auth import OPEN, owner_of, tenant_for
from server.settings import Settings
from server.state import jobs
from server.state.db import add_missing_columns, init_db, make_engine, make_sessions
from server.state.models import Job
from tests.support.service_process import post_scan, scan_file

JOB_ROUTES = ("", "/result", "/result?format=ifc", "/objects", "/report")


def _client(url: str, key: str) -> httpx.Client:
    return httpx.Client(base_url=url, headers={"Authorization": f"Bearer {key}"}, timeout=30)


def _answer(response: httpx.Response) -> tuple[int, Any]:
    """Status and body, the job id in the body replaced (to compare two ids' answers)."""
    body = response.text
    for part in response.url.path.split("/"):
        if len(part) == 32:
            body = body.replace(part, "<id>")
    return response.status_code, body


def test_a_key_sees_only_its_own_jobs_and_others_are_404_like_unknown_ids(locked, scans) -> None:
    room = scan_file(scans, ".ply", points=1000, seed=11)
    unknown = uuid.uuid4().hex
    with (
        _client(locked.url, "key-one") as one,
        _client(locked.url, "key-two") as two,
        _client(locked.url, "key-admin") as admin,
    ):
        mine = post_scan(one, room).json()["id"]
        theirs = post_scan(two, room).json()["id"]

        listed = {j["id"] for j in one.get("/v1/jobs", params={"limit": 500}).json()["items"]}
        assert mine in listed and theirs not in listed
        assert one.get("/v1/jobs", params={"limit": 500}).json()["total"] == len(listed)
        assert one.get(f"/v1/jobs/{mine}").status_code == 200
        for route in JOB_ROUTES:  # existence does not leak: the same answer as no such job
            foreign = one.get(f"/v1/jobs/{theirs}{route}")
            assert foreign.status_code == 404, (route, foreign.text)
            assert _answer(foreign) == _answer(one.get(f"/v1/jobs/{unknown}{route}"))
        refused = one.delete(f"/v1/jobs/{theirs}")  # neither cancel nor delete
        assert _answer(refused) == _answer(one.delete(f"/v1/jobs/{unknown}"))
        assert two.get(f"/v1/jobs/{theirs}").json()["status"] == "queued"

        everything = admin.get("/v1/jobs", params={"limit": 500}).json()
        assert {mine, theirs} <= {j["id"] for j in everything["items"]}
        assert everything["total"] >= one.get("/v1/jobs").json()["total"] + 1
        assert admin.get(f"/v1/jobs/{theirs}").status_code == 200
        assert admin.get(f"/v1/jobs/{theirs}/result").status_code == 409  # queued: no result
        assert admin.delete(f"/v1/jobs/{theirs}").json()["status"] == "cancelled"
        assert admin.delete(f"/v1/jobs/{theirs}").status_code == 204
        assert one.delete(f"/v1/jobs/{mine}").status_code == 202

    table = sqlite3.connect(locked.data_dir / "jobs.sqlite3")
    try:
        (owner,) = table.execute("SELECT owner FROM jobs WHERE id = ?", (mine,)).fetchone()
        dump = "\n".join(str(row) for row in table.execute("SELECT * FROM jobs"))
    finally:
        table.close()
    assert owner == owner_of("key-one") and len(owner) == 64
    assert "key-one" not in dump and "key-two" not in dump  # a hash, never the key


def test_tenants_of_keys_admin_keys_and_an_open_service() -> None:
    keyed = Settings(api_keys=["key-one"], admin_keys=["key-admin"])
    one, admin = tenant_for(keyed, "key-one"), tenant_for(keyed, "key-admin")
    assert one is not None and one.scope == owner_of("key-one")
    assert admin is not None and admin.scope is None and admin.owner == owner_of("key-admin")
    assert tenant_for(keyed, "key-two") is None and tenant_for(keyed, None) is None
    only_admins = Settings(admin_keys=["key-admin"])
    assert only_admins.keys_required and tenant_for(only_admins, None) is None
    assert tenant_for(Settings(), None) == OPEN and OPEN.scope is None  # open: every job
    assert owner_of("key-one") != owner_of("key-two")


def _old_jobs_table(engine: Any) -> None:
    """The job table as services before tenants created it (no ``owner``), with one job."""
    old = MetaData()
    columns: list[Column[Any]] = [c._copy() for c in Job.__table__.c if c.name != "owner"]
    Table("jobs", old, *columns)
    old.create_all(engine)
    with engine.begin() as conn:
        conn.execute(
            text(
                "INSERT INTO jobs (id, filename, format, size_bytes, status, progress, config,"
                " network, created_at, attempts, cancel_requested) VALUES (:id, 'old.ply',"
                " 'ply', 1, 'succeeded', 1.0, '{}', 'randlanet', CURRENT_TIMESTAMP, 1, :no)"
            ),
            {"id": "a" * 32, "no": False},
        )


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
def test_an_old_job_table_gets_the_owner_column(
    backend: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    url = None if backend == "sqlite" else request.getfixturevalue("postgres_url")
    engine = make_engine(Settings(data_dir=tmp_path, database_url=url))
    try:
        _old_jobs_table(engine)
        assert "owner" not in {c["name"] for c in inspect(engine).get_columns("jobs")}
        init_db(engine)  # what every service process does at start
        assert "owner" in {c["name"] for c in inspect(engine).get_columns("jobs")}
        assert "ix_jobs_owner" in {i["name"] for i in inspect(engine).get_indexes("jobs")}
        assert add_missing_columns(engine) == []  # the next process finds nothing to do
        with make_sessions(engine)() as session:
            # the old job belongs to nobody in particular: admins and open mode see it ...
            assert jobs.get_job(session, "a" * 32).filename == "old.ply"
            assert jobs.count_jobs(session) == 1
            # ... a key's tenant does not
            with pytest.raises(JobNotFound):
                jobs.get_job(session, "a" * 32, owned_by=owner_of("key-one"))
            assert jobs.list_jobs(session, owned_by=owner_of("key-one")) == []
            new = uuid.uuid4().hex
            jobs.create_job(
                session,
                job_id=new,
                filename="new.ply",
                fmt="ply",
                size_bytes=1,
                points=10,
                config={},
                network="randlanet",
                owner=owner_of("key-one"),
            )
            assert [v.id for v in jobs.list_jobs(session, owned_by=owner_of("key-one"))] == [new]
    finally:
        engine.dispose()
