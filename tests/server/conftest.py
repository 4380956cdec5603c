"""Fixtures of the server tests: a locked service, job configs (the shared `service` is in
tests/conftest.py)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from service_process import Service, running


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
    """A service with API keys, a 64 KiB upload limit and no worker (jobs stay queued)."""
    folder = tmp_path_factory.mktemp("locked")
    with running(folder, workers=0, api_keys="key-one,key-two", max_upload_bytes=65536) as svc:
        yield svc
