"""Result files in the format a client asks for, and a job's objects and rooms.

The IFC model is built from the job's report (its ``objects`` and ``rooms`` sections) on the
first request and kept, like a LAS conversion.

The worker writes ``result.ply`` (every field of ``jointseg segment``); LAS and LAZ are converted
from it with the same reader and writer on the first request and kept, so jobs nobody downloads
as LAS cost nothing. A lock per file keeps two concurrent requests from converting twice; the
atomic writer keeps a reader from ever seeing half a file.
"""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path

from jointseg.exceptions import JobStateError
from jointseg.io import read_scan, write_scan
from jointseg.objects.ifc import write_ifc
from jointseg.objects.records import LayoutReport
from server.storage import ResultFormat, Storage

log = logging.getLogger(__name__)

_locks: dict[Path, threading.Lock] = {}
_locks_guard = threading.Lock()


def _lock_for(path: Path) -> threading.Lock:
    with _locks_guard:
        return _locks.setdefault(path, threading.Lock())


def layout_of(storage: Storage, job_id: str) -> LayoutReport:
    """The objects, rooms and walls of a succeeded job, from its report.

    Raises
    ------
    JobStateError
        When the job has no report, or its run found no objects or rooms.
    """
    path = storage.report_path(job_id)
    if not path.is_file():
        raise JobStateError(f"job {job_id} has no report")
    return LayoutReport.from_report(json.loads(path.read_text(encoding="utf-8")))


def result_file(storage: Storage, job_id: str, fmt: ResultFormat) -> Path:
    """The job's result in ``fmt``, converted from the PLY result when needed (blocking).

    Raises
    ------
    JobStateError
        When the job has no result (it has not succeeded, or its files were deleted).
    """
    ply = storage.result_path(job_id, "ply")
    if not ply.is_file():
        raise JobStateError(f"job {job_id} has no result")
    target = storage.result_path(job_id, fmt)
    if target.is_file():
        return target
    with _lock_for(target):
        if not target.is_file() and fmt == "ifc":
            write_ifc(layout_of(storage, job_id), target, name=job_id)
            log.info("job %s: IFC model written", job_id)
        elif not target.is_file():
            write_scan(read_scan(ply, max_points=1 << 40), target)
            log.info("job %s: result converted to %s", job_id, fmt)
    with _locks_guard:
        _locks.pop(target, None)
    return target
