"""Hostile uploads (issue 44, point 1): headers that lie about their size and files that inflate
are refused from what they declare, before anything is allocated, and the API process never
reads a scan's points: three at once leave its peak memory within 300 MB of where it was."""

from __future__ import annotations

import time
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from jointseg.exceptions import ScanFormatError
from jointseg.io import probe_scan, read_scan
from jointseg.io.stream import open_chunks
from tests.support.hostile_files import CLAIMED, HOSTILE, bomb_npz, liar_laz
from tests.support.service_process import left_in_incoming, post_scan

#: Largest growth of the API's peak resident memory under three hostile uploads at once.
MAX_GROWTH_MB = 300


def _status_mb(pid: int, key: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no {key} in /proc/{pid}/status")


@pytest.fixture(scope="module")
def hostile(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("hostile")
    return {kind: make(folder) for kind, make in HOSTILE.items()}


@pytest.mark.parametrize("kind", ["laz", "npz"])  # the PLY and PCD liars were refused before
def test_three_hostile_uploads_at_once_are_refused_within_bounded_api_memory(
    service, hostile, kind
) -> None:
    pid = service.api.popen.pid  # `jointseg serve` runs the API in its own process
    Path(f"/proc/{pid}/clear_refs").write_text("5")  # peak (VmHWM) := current
    before = _status_mb(pid, "VmRSS")
    path = hostile[kind]
    with service.http() as http:
        total = http.get("/v1/jobs").json()["total"]
        began = time.monotonic()
        with ThreadPoolExecutor(3) as pool:
            answers = list(pool.map(lambda _: post_scan(http, path), range(3)))
        took = time.monotonic() - began
        assert http.get("/v1/jobs").json()["total"] == total  # no job queued
    growth = _status_mb(pid, "VmHWM") - before
    assert growth < MAX_GROWTH_MB, f"API peak memory grew by {growth:.0f} MB"
    for answer in answers:
        assert answer.status_code == 422, answer.text
        body = answer.json()
        assert set(body) == {"error", "detail"} and body["error"] == "ScanFormatError", body
        assert path.name in body["detail"] and f"{CLAIMED:,}" in body["detail"], body
        assert str(service.data_dir) not in body["detail"], body  # no server path
    assert took < 30, f"three refusals took {took:.1f} s"
    assert left_in_incoming(service.data_dir) == []


def test_readers_refuse_a_laz_header_claiming_more_than_the_file_can_hold(tmp_path) -> None:
    path = liar_laz(tmp_path)
    for read in (probe_scan, read_scan, open_chunks):
        with pytest.raises(ScanFormatError, match="max_inflation"):
            read(path)


def test_readers_refuse_an_npz_inflating_beyond_the_ceiling(tmp_path) -> None:
    path = bomb_npz(tmp_path, points=2_000_000)  # 24 MB of zeros in 23 KB
    for read in (probe_scan, read_scan):
        with pytest.raises(ScanFormatError, match="max_inflation"):
            read(path, max_inflation=200)
    assert probe_scan(path).n_points == 2_000_000  # the library's default ceiling is higher


def test_npz_member_declaring_more_than_the_zip_holds_is_refused(tmp_path) -> None:
    path = tmp_path / "short.npz"
    with zipfile.ZipFile(path, "w") as zf, zf.open("xyz.npy", "w") as fh:
        header = {"descr": "<f8", "fortran_order": False, "shape": (10**9, 3)}
        np.lib.format.write_array_header_1_0(fh, header)
        fh.write(np.zeros((10, 3)).tobytes())  # ten rows of the billion declared
    for read in (probe_scan, read_scan):
        with pytest.raises(ScanFormatError, match="declares shape"):
            read(path, max_points=2 * 10**9)
