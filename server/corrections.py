"""A job's labels versions: the corrections users make by segment, point or box, and each
version's files. Plain functions of a session factory and a :class:`Storage`, so the API and
the viewer process (which holds both, but no app) share them.

Version 0 is the run's own ``result.ply`` and is never rewritten. Version N >= 1 is one array,
``jobs/<id>/labels/v<N>.npy`` (the user's class per point, -1 where none), plus a row in
``label_versions``; everything downloaded of it (scan, objects, IFC, report) is made from
version 0 and that array by :mod:`jointseg.labels.version` on the first request, and kept.

Concurrency: a correction names the version it builds on (``If-Match``: its ETag, ``"v3"``).
Corrections of one job are serialised by a lock file (``flock``, across the processes sharing
the data directory); the unique (job, version) row decides the rest: the array is written
before the row is committed and removed again when the row cannot be. So a version's array
exists whenever its row does, and a refused correction leaves nothing behind.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Literal

import numpy as np

from jointseg.exceptions import (
    JobNotFound,
    JobStateError,
    PreconditionFailed,
    PreconditionRequired,
)
from jointseg.io.atomic import atomic_open
from jointseg.labels.edits import EditList
from server.results import convert_result, layout_from, layout_of, lock_for, result_file
from server.schemas import JobView, LabelsState, LabelsVersion
from server.state import jobs, labels
from server.state.db import SessionFactory
from server.storage import Storage

log = logging.getLogger(__name__)

#: What a version offers to download (as :data:`server.results.DOWNLOADS`).
VersionKind = Literal["ply", "las", "laz", "ifc", "objects", "report"]
VERSION_KINDS: tuple[VersionKind, ...] = ("ply", "las", "laz", "ifc", "objects", "report")
#: A version's files in its folder (``labels/v<N>/``); the report is written last, so its
#: presence says the folder is complete.
_FILE_NAMES: dict[VersionKind, str] = {
    "ply": "result.ply",
    "las": "result.las",
    "laz": "result.laz",
    "ifc": "result.ifc",
    "objects": "objects.json",
    "report": "report.json",
}
#: Most points a result may have to be read whole for a correction (the worker wrote it).
_READ_ANY = 1 << 40


def etag(version: int) -> str:
    """The strong ETag of labels version ``version``: ``"v3"``."""
    return f'"v{int(version)}"'


def succeeded_job(sessions: SessionFactory, job_id: str, *, owned_by: str | None) -> JobView:
    """The job when ``owned_by`` may see it and it succeeded.

    Raises
    ------
    JobNotFound
        For an unknown id or another owner's job.
    JobStateError
        When the job has not succeeded (it has no labels to correct).
    """
    with sessions() as session:
        view = jobs.get_job(session, job_id, owned_by=owned_by)
    if view.status != "succeeded":
        raise JobStateError(f"job {job_id} is {view.status}; no result, labels or report yet")
    return view


def labels_state(
    sessions: SessionFactory, storage: Storage, job_id: str, *, owned_by: str | None
) -> LabelsState:
    """The job's current labels version, its ETag and every version (0 first).

    Raises
    ------
    JobNotFound, JobStateError
        As :func:`succeeded_job`.
    """
    view = succeeded_job(sessions, job_id, owned_by=owned_by)
    with sessions() as session:
        history = labels.versions(session, job_id)
    first = LabelsVersion(version=0, created_at=view.finished_at)
    current = history[-1].version if history else 0
    return LabelsState(
        job_id=job_id, version=current, etag=etag(current), history=[first, *history]
    )


def resolve_version(
    sessions: SessionFactory, job_id: str, version: int | None, *, owned_by: str | None
) -> tuple[JobView, int]:
    """The job and the labels version a download asked for (None: the current one).

    Raises
    ------
    JobNotFound
        For an unknown job, or a version the job does not have (naming the current one).
    JobStateError
        When the job has not succeeded.
    """
    view = succeeded_job(sessions, job_id, owned_by=owned_by)
    if version is None:
        return view, view.labels_version
    if not 0 <= version <= view.labels_version:
        raise JobNotFound(
            f"job {job_id} has no labels version {version}; its versions are 0 to "
            f"{view.labels_version}"
        )
    return view, version


def require_if_match(job_id: str, if_match: str | None) -> str:
    """``if_match``; a correction that does not say which version it builds on is refused.

    Raises
    ------
    PreconditionRequired
        Without ``if_match``.
    """
    if if_match is None:
        raise PreconditionRequired(
            f"job {job_id}: send If-Match with the labels' ETag (GET /v1/jobs/{job_id}/labels)"
        )
    return if_match


@contextlib.contextmanager
def _job_lock(storage: Storage, job_id: str) -> Iterator[None]:
    """Hold the job's corrections lock (a ``flock`` on ``labels/.lock``; dropped by the kernel
    if the process dies)."""
    folder = storage.labels_dir(job_id)
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(folder / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def user_labels(storage: Storage, job_id: str, version: int) -> np.ndarray | None:
    """Labels version ``version``'s user class per point (int16, -1 none); None for version 0
    or a version without its array."""
    if version <= 0:
        return None
    path = storage.labels_path(job_id, version)
    if not path.is_file():
        return None
    return np.asarray(np.load(path, allow_pickle=False), dtype=np.int16)


def _save_array(path: Path, values: np.ndarray) -> None:
    """``values`` as a ``.npy`` file, atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path) as fh:
        np.save(fh, np.asarray(values, dtype=np.int16), allow_pickle=False)


def correct(
    sessions: SessionFactory,
    storage: Storage,
    job_id: str,
    edits: EditList,
    *,
    if_match: str | None,
    owner: str | None,
    owned_by: str | None,
) -> LabelsState:
    """Apply ``edits`` over the current labels version as a new version; its state.

    Parameters
    ----------
    if_match : str, optional
        The ETag of the version the edits build on (:func:`etag`); compared exactly.
    owner : str, optional
        Who corrects (:func:`server.api.auth.owner_of` the key); None in open mode.
    owned_by : str, optional
        The tenant's scope: another owner's job is :class:`JobNotFound`.

    Raises
    ------
    JobNotFound, JobStateError
        As :func:`succeeded_job`.
    PreconditionRequired
        Without ``if_match``.
    PreconditionFailed
        When ``if_match`` is not the current version's ETag, or another correction made the
        next version meanwhile.
    ConfigError
        For a segment or point id out of range; nothing is written.
    """
    from jointseg.io import read_scan
    from jointseg.labels.edits import apply_edits
    from jointseg.labels.version import check_result, corrected_points, machine_labels

    succeeded_job(sessions, job_id, owned_by=owned_by)
    if_match = require_if_match(job_id, if_match)
    with _job_lock(storage, job_id):
        with sessions() as session:
            current = labels.current_version(session, job_id)
        if if_match.strip() != etag(current):
            raise PreconditionFailed(
                f"job {job_id}: If-Match {if_match.strip()} is not the current labels version "
                f"{etag(current)}; read the labels again and repeat the change on them"
            )
        scan = read_scan(storage.result_path(job_id, "ply"), max_points=_READ_ANY)
        check_result(scan, name=f"job {job_id}'s result")
        outcome = apply_edits(
            edits,
            machine_labels=machine_labels(scan),
            user_label=user_labels(storage, job_id, current),
            segment=scan.fields["segment"],
            xyz=scan.xyz,
        )
        version = current + 1
        path = storage.labels_path(job_id, version)
        _save_array(path, outcome.user_label)
        try:
            with sessions() as session:
                labels.add_version(
                    session,
                    job_id,
                    version,
                    owner=owner,
                    points_changed=outcome.changed,
                    points_corrected=corrected_points(scan, outcome.user_label),
                    edits=len(edits.edits),
                )
        except BaseException:
            path.unlink(missing_ok=True)
            raise
    log.info("job %s: labels version %d, %d points changed", job_id, version, outcome.changed)
    return labels_state(sessions, storage, job_id, owned_by=owned_by)


def version_file(storage: Storage, job_id: str, version: int, kind: VersionKind) -> Path:
    """A labels version's ``kind`` file, made on the first request and kept (blocking).

    Version 0 is the run's own files (:func:`server.results.result_file`, its report and
    its objects). A later version's scan carries ``fused_label`` = the version's labels and
    ``user_label`` (LAS: classification 64 + the class where corrected); its objects, IFC and
    report are made from its labels. The caller checks that the job succeeded, is the tenant's
    and has this version (:func:`resolve_version`).

    Raises
    ------
    JobStateError
        When the job has no result or report, or for ``objects`` and ``ifc`` when its run found
        no objects or rooms.
    JobNotFound
        For a version without its array.
    """
    if kind not in VERSION_KINDS:
        raise ValueError(f"kind must be one of {VERSION_KINDS}, got {kind!r}")
    if version == 0:
        return _run_file(storage, job_id, kind)
    folder = _made_version(storage, job_id, version)
    target = folder / _FILE_NAMES[kind]
    if kind in ("las", "laz", "ifc"):
        return convert_result(
            folder / "result.ply", folder / "report.json", target, kind, name=job_id
        )
    if kind == "objects" and not target.is_file():
        layout_from(folder / "report.json")  # the run's own "no objects or rooms" error
    return target


def _run_file(storage: Storage, job_id: str, kind: VersionKind) -> Path:
    """Version 0's ``kind``: the run's own result, report, or its objects written once."""
    if kind == "report":
        path = storage.report_path(job_id)
        if not path.is_file():
            raise JobStateError(f"job {job_id} has no report")
        return path
    if kind != "objects":
        return result_file(storage, job_id, kind)
    target = storage.job_dir(job_id) / "objects.json"
    if not target.is_file():
        layout = layout_of(storage, job_id)
        with lock_for(target), atomic_open(target) as fh:
            fh.write(json.dumps(layout.model_dump(mode="json"), indent=1).encode())
    return target


def _made_version(storage: Storage, job_id: str, version: int) -> Path:
    """The folder of version ``version``'s scan, objects and report, made once under a lock."""
    folder = storage.version_dir(job_id, version)
    if (folder / "report.json").is_file():
        return folder
    with lock_for(folder):
        if not (folder / "report.json").is_file():
            _make_version(storage, job_id, version, folder)
    return folder


def _make_version(storage: Storage, job_id: str, version: int, folder: Path) -> None:
    """Write version ``version``'s ``result.ply``, ``objects.json`` (when the run found objects)
    and, last, ``report.json``."""
    from jointseg.io import read_scan, write_scan
    from jointseg.labels.version import version_outputs

    user = user_labels(storage, job_id, version)
    if user is None:
        raise JobNotFound(f"job {job_id} has no labels version {version}")
    ply = storage.result_path(job_id, "ply")
    if not ply.is_file():
        raise JobStateError(f"job {job_id} has no result")
    scan = read_scan(ply, max_points=_READ_ANY)
    report_path = storage.report_path(job_id)
    report = json.loads(report_path.read_text("utf-8")) if report_path.is_file() else None
    found = report is not None and report.get("rooms") is not None  # the run found objects
    labelled, layout, body = version_outputs(scan, user, report, version=version, objects=found)
    folder.mkdir(parents=True, exist_ok=True)
    write_scan(labelled, folder / "result.ply")
    if layout is not None:
        with atomic_open(folder / "objects.json") as fh:
            fh.write(json.dumps(layout.report.model_dump(mode="json"), indent=1).encode())
    with atomic_open(folder / "report.json") as fh:
        fh.write(json.dumps(body, indent=1).encode())
    log.info("job %s: labels version %d's files written", job_id, version)
