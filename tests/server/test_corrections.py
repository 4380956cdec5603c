"""Labels versions in process (server.corrections over SQLite and a data folder): the ETag
precondition, nothing written on a refusal, the version's array and files, the loser of a race
for a version, and a deleted job taking its versions along."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jointseg.exceptions import (
    ConfigError,
    JobNotFound,
    JobStateError,
    PreconditionFailed,
    PreconditionRequired,
)
from jointseg.io import read_scan, write_scan
from jointseg.labels.edits import parse_edits
from jointseg.synth import make_room
from server import corrections
from server.settings import Settings
from server.state import jobs, labels
from server.state.db import SessionFactory, init_db, make_engine, make_sessions
from server.state.models import LabelVersion
from server.storage import Storage

POINTS = 3000


@pytest.fixture
def setup(tmp_path: Path) -> tuple[SessionFactory, Storage, str, np.ndarray]:
    """A succeeded job (no report) whose result has 30 segments of 100 points; its labels."""
    engine = make_engine(Settings(data_dir=tmp_path))
    init_db(engine)
    sessions = make_sessions(engine)
    storage = Storage(tmp_path)
    job_id = "a" * 32
    room = make_room(3, points=POINTS)
    fused = np.asarray(room.labels, dtype=np.int32)
    segment = (np.arange(POINTS) // 100).astype(np.int32)
    storage.job_dir(job_id).mkdir(parents=True)
    write_scan(
        room.with_fields(fused_label=fused, segment=segment),
        storage.result_path(job_id, "ply"),
    )
    with sessions() as session:
        jobs.create_job(
            session,
            job_id=job_id,
            filename="office.ply",
            fmt="ply",
            size_bytes=1,
            points=POINTS,
            config={},
            network="randlanet",
            owner="someone",
        )
        from server.state.models import Job

        row = session.get(Job, job_id)
        assert row is not None
        row.status = "succeeded"
        session.commit()
    yield sessions, storage, job_id, fused
    engine.dispose()


def _files(storage: Storage, job_id: str) -> list[str]:
    folder = storage.labels_dir(job_id)
    return sorted(p.name for p in folder.iterdir() if p.name != ".lock") if folder.exists() else []


def test_a_correction_needs_the_current_etag_and_writes_nothing_otherwise(setup) -> None:
    sessions, storage, job_id, fused = setup
    edits = parse_edits({"edits": [{"segments": [0, 2], "label": "table"}]})
    state = corrections.labels_state(sessions, storage, job_id, owned_by=None)
    assert (state.version, state.etag, len(state.history)) == (0, '"v0"', 1)

    def correct(if_match: str | None, owned_by: str | None = None):
        return corrections.correct(
            sessions, storage, job_id, edits, if_match=if_match, owner="me", owned_by=owned_by
        )

    with pytest.raises(PreconditionRequired):
        correct(None)
    with pytest.raises(PreconditionFailed):
        correct('"v1"')
    with pytest.raises(PreconditionFailed):
        correct("v0")  # the tag exactly, quotes and all
    with pytest.raises(JobNotFound):
        correct('"v0"', owned_by="another")
    bad = parse_edits({"edits": [{"points": [POINTS], "label": 1}]})
    with pytest.raises(ConfigError, match=r"edits\[0\]\.points: point 3000 out of range"):
        corrections.correct(
            sessions, storage, job_id, bad, if_match='"v0"', owner=None, owned_by=None
        )
    assert _files(storage, job_id) == []
    assert corrections.labels_state(sessions, storage, job_id, owned_by=None).version == 0

    state = correct('"v0"')
    assert (state.version, state.etag) == (1, '"v1"')
    entry = state.history[1]
    table = 7  # S3DIS order
    expected = int(
        np.count_nonzero(fused[:100] != table) + np.count_nonzero(fused[200:300] != table)
    )
    assert (entry.owner, entry.edits, entry.points_changed) == ("me", 1, expected)
    assert entry.points_corrected == expected
    user = corrections.user_labels(storage, job_id, 1)
    assert user is not None and user.dtype == np.int16
    assert set(np.flatnonzero(user >= 0)) == set(range(100)) | set(range(200, 300))
    assert _files(storage, job_id) == ["v1.npy"]
    with pytest.raises(PreconditionFailed):
        correct('"v0"')  # stale now
    with sessions() as session:
        assert jobs.get_job(session, job_id).labels_version == 1


def test_a_versions_files_carry_its_labels(setup) -> None:
    sessions, storage, job_id, fused = setup
    edits = parse_edits({"edits": [{"box": {"min": [-1e9] * 3, "max": [1e9] * 3}, "label": 0}]})
    corrections.correct(
        sessions, storage, job_id, edits, if_match='"v0"', owner=None, owned_by=None
    )
    ply = corrections.version_file(storage, job_id, 1, "ply")
    assert ply.parent == storage.version_dir(job_id, 1)
    scan = read_scan(ply)
    assert np.all(scan.fields["fused_label"] == 0) and np.all(scan.fields["user_label"] == 0)
    import laspy

    las = laspy.read(corrections.version_file(storage, job_id, 1, "las"))
    assert set(np.unique(np.asarray(las.classification))) == {64}  # 64 + ceiling (0)
    original = read_scan(corrections.version_file(storage, job_id, 0, "ply"))
    assert np.array_equal(original.fields["fused_label"], fused)  # version 0 untouched
    assert "user_label" not in original.fields
    with pytest.raises(JobStateError):  # this run has no report: no objects either
        corrections.version_file(storage, job_id, 1, "objects")
    with pytest.raises(JobNotFound):
        corrections.version_file(storage, job_id, 2, "ply")


def test_the_loser_of_a_race_for_a_version_gets_412_and_leaves_no_file(
    setup, monkeypatch: pytest.MonkeyPatch
) -> None:
    sessions, storage, job_id, _ = setup
    with sessions() as session:  # another process committed version 1 meanwhile
        labels.add_version(
            session, job_id, 1, owner=None, points_changed=1, points_corrected=1, edits=1
        )
    monkeypatch.setattr(labels, "current_version", lambda session, job: 0)  # read before it
    edits = parse_edits({"edits": [{"segments": [1], "label": "wall"}]})
    with pytest.raises(PreconditionFailed, match="meanwhile"):
        corrections.correct(
            sessions, storage, job_id, edits, if_match='"v0"', owner=None, owned_by=None
        )
    assert _files(storage, job_id) == []
    with sessions() as session:
        assert session.query(LabelVersion).count() == 1


def test_deleting_a_job_deletes_its_versions(setup) -> None:
    sessions, storage, job_id, _ = setup
    edits = parse_edits({"edits": [{"segments": [1], "label": "wall"}]})
    corrections.correct(
        sessions, storage, job_id, edits, if_match='"v0"', owner=None, owned_by=None
    )
    with sessions() as session:
        jobs.delete_job_row(session, job_id)
        assert session.query(LabelVersion).count() == 0


def test_a_correction_naming_more_ids_than_the_limit_is_refused_naming_the_edit(
    tmp_path: Path,
) -> None:
    from server.api.routes.labels import parse_edit_body

    raw = b'{"edits": [{"segments": [0, 1, 2], "label": 1}, {"points": [4, 5, 6], "label": 2}]}'
    parse_edit_body(raw, Settings(data_dir=tmp_path, max_points=6))  # at the limit: taken
    with pytest.raises(ConfigError, match=r"edits\[1\]: more than 5 ids in one request"):
        parse_edit_body(raw, Settings(data_dir=tmp_path, max_points=5))
