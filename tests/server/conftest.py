"""Fixtures of the server tests: a locked service, job configs, a fresh PostgreSQL database
and Redis queue name (the shared `service` is in tests/conftest.py)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.support.service_process import REDIS, Service, fresh_database, running


@pytest.fixture(scope="session")
def job_config(random_weights: Path) -> dict[str, Any]:
    """A job config using the small random network, so jobs take about a second."""
    return {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 1}


@pytest.fixture(scope="session")
def scans(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder for synthetic scans (see :func:`scan_file`)."""
    return tmp_path_factory.mktemp("scans")


@pytest.fixture(scope="session")
def locked(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Service]:
    """A service with API keys (``key-admin`` an admin key: it sees every job), a 64 KiB upload
    limit and no worker (jobs stay queued)."""
    folder = tmp_path_factory.mktemp("locked")
    with running(
        folder,
        workers=0,
        api_keys="key-one,key-two",
        admin_keys="key-admin",
        max_upload_bytes=65536,
    ) as svc:
        yield svc


@pytest.fixture
def postgres_url() -> Iterator[str]:
    """A fresh database for this test, dropped afterwards."""
    with fresh_database() as url:
        yield url


@pytest.fixture
def redis_queue() -> Iterator[str]:
    """A fresh queue name (Redis key prefix), its keys deleted afterwards."""
    redis = pytest.importorskip("redis")
    client = redis.Redis.from_url(REDIS, socket_connect_timeout=3)
    try:
        client.ping()
    except redis.RedisError as exc:
        pytest.skip(f"Redis at {REDIS} not reachable (.ci/run starts it): {exc}")
    name = f"jointseg-test-{uuid.uuid4().hex[:12]}"
    try:
        yield name
    finally:
        keys = list(client.scan_iter(match=f"*{name}*"))
        if keys:
            client.delete(*keys)
        client.close()
