"""Upload file names and storage paths, without a server."""

from __future__ import annotations

import pytest

from jointseg.exceptions import ConfigError, JobNotFound, UnsupportedFormatError
from server.api.uploads import safe_filename, upload_suffix
from server.storage import Storage


@pytest.mark.parametrize(
    ("raw", "safe"),
    [
        ("room.ply", "room.ply"),
        ("../../etc/room.ply", "room.ply"),
        ("C:\\scans\\..\\room.las", "room.las"),
        ("dir/\x00ro\x07om\n.ply", "room.ply"),
        ("  .hidden.ply ", "hidden.ply"),
        ("été.ply", "été.ply"),
    ],
)
def test_safe_filename(raw, safe) -> None:
    assert safe_filename(raw) == safe


@pytest.mark.parametrize("raw", ["", "../", "...", "/", "x" * 252 + "é.ply"])
def test_unusable_filenames(raw) -> None:
    with pytest.raises(ConfigError):
        safe_filename(raw)


def test_upload_suffix() -> None:
    assert upload_suffix("Room.PLY") == ".ply"
    with pytest.raises(UnsupportedFormatError, match="supported: .ply"):
        upload_suffix("room.pt")


def test_storage_paths_and_delete(tmp_path) -> None:
    storage = Storage(tmp_path)
    job_id = "ab" * 16
    assert storage.result_path(job_id, "laz") == tmp_path / "jobs" / job_id / "result.laz"
    for bad in ("../" + "a" * 29, "A" * 32, "a" * 31, "a" * 32 + "/x"):
        with pytest.raises(JobNotFound):
            storage.job_dir(bad)
    with pytest.raises(JobNotFound):
        storage.upload_path(job_id)  # nothing stored yet
    tmp = storage.new_incoming(".ply")
    tmp.write_bytes(b"ply")
    stored = storage.commit_upload(tmp, job_id, ".PLY")
    assert stored == storage.upload_path(job_id) and stored.read_bytes() == b"ply"
    assert not tmp.exists()
    storage.write_bytes(storage.report_path(job_id), b"{}")
    assert sorted(p.name for p in storage.job_dir(job_id).iterdir()) == ["input.ply", "report.json"]
    storage.delete(job_id)
    assert not storage.job_dir(job_id).exists() and list(storage.incoming_dir.iterdir()) == []
    storage.delete(job_id)  # nothing left: no error
