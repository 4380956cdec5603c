"""A garbage ``.e57`` and bad weights through the service (issue 44): the API's 4xx and a job's
stored error are one line naming the user's file, without libE57Format's or torch's debug text
and without any path on the server."""

from __future__ import annotations

import os
import re
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.support.service_process import left_in_incoming, post_scan, scan_file, wait_for

#: What a library's dump carries and a user's message must not.
DEBUG_TEXT = (
    "libE57",
    ".cpp",
    "Traceback",
    "Debug info",
    "Got an e57 exception",
    "enforce fail",
    "Unsupported operand",
    "weights_only",
)
#: An absolute path inside a sentence.
ABSOLUTE = re.compile(r"(?<![\w.:])/[\w.~-]+/")


def assert_clean(text: str, *server_folders: Path) -> None:
    """One line, no library debug text, no absolute path, no server folder."""
    assert "\n" not in text, text
    for debug in DEBUG_TEXT:
        assert debug not in text, text
    assert ABSOLUTE.search(text) is None, text
    for folder in server_folders:
        assert str(folder) not in text, text


def garbage_e57(folder: Path, case: str) -> Path:
    """The E57 magic, then noise or zeros: libE57Format opens it and fails on the checksum."""
    body = np.random.default_rng(1).bytes(4000) if case == "noise" else bytes(4000)
    path = folder / f"garbage-{case}.e57"
    path.write_bytes(b"ASTM-E57" + body)
    return path


@pytest.mark.parametrize("case", ["noise", "zeros"])
def test_a_garbage_e57_upload_is_a_one_line_422(locked, tmp_path: Path, case: str) -> None:
    path = garbage_e57(tmp_path, case)
    with locked.http() as http:
        before = http.get("/v1/jobs").json()["total"]
        response = post_scan(http, path)
        assert response.status_code == 422, response.text
        assert response.headers["content-type"] == "application/json"
        body = response.json()
        assert set(body) == {"error", "detail"}
        assert body["error"] == "ScanFormatError"
        detail = body["detail"]
        assert detail.startswith(f"{path.name}: not a readable E57 file")
        assert_clean(detail, locked.data_dir, tmp_path)
        assert "/" not in detail
        assert http.get("/v1/jobs").json()["total"] == before
        assert left_in_incoming(locked.data_dir) == []


def _bad_weights(path: Path, case: str) -> None:
    """Weights a job may name (they lie in the weights folder) that do not load."""
    if case == "noise":
        path.write_bytes(np.random.default_rng(2).bytes(5000))
    elif case == "empty":
        path.write_bytes(b"")
    else:  # a checkpoint whose tensors fit no network
        torch.save(
            {"format": "jointseg-randlanet/1", "config": {}, "state_dict": {"a": torch.zeros(2)}},
            path,
        )


@pytest.fixture
def weights_file() -> Iterator[Path]:
    """A fresh name in the test services' weights folder, removed afterwards."""
    folder = Path(os.environ["JOINTSEG_TEST_WEIGHTS_DIR"])
    path = folder / f"bad-{uuid.uuid4().hex[:8]}.pt"
    yield path
    path.unlink(missing_ok=True)


@pytest.mark.parametrize("case", ["noise", "empty", "wrong-tensors"])
def test_a_job_with_bad_weights_fails_with_a_one_line_error(
    service, scans: Path, weights_file: Path, case: str
) -> None:
    _bad_weights(weights_file, case)
    room = scan_file(scans, ".ply", points=1000, seed=7)
    config = {"network": {"weights": weights_file.name, "device": "cpu"}, "seed": 1}
    with service.http() as http:
        created = post_scan(http, room, config)
        assert created.status_code == 201, created.text
        job = wait_for(http, created.json()["id"])
    assert job["status"] == "failed", job
    error = job["error"]
    assert weights_file.name in error  # the name the job gave ...
    assert "checkpoint" in error or "weights" in error  # ... and what is wrong with it
    assert_clean(error, weights_file.parent, service.data_dir)
