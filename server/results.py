"""Result files in the format a client asks for, and a job's objects and rooms.

The IFC model is built from the job's report (its ``objects`` and ``rooms`` sections) on the
first request and kept, like a LAS conversion.

The worker writes ``result.ply`` (every field of ``jointseg segment``); LAS and LAZ are converted
from it with the same reader and writer on the first request and kept, so jobs nobody downloads
as LAS cost nothing. A lock per file keeps two concurrent requests from converting twice; the
atomic writer keeps a reader from ever seeing half a file.

The job page and the viewer offer the same downloads under the same names
(:data:`DOWNLOADS`, :func:`download_name`): the routes send the name in ``Content-Disposition``,
the page saves under it, and the viewer, which holds no key, reads the files through these
functions rather than through an address.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Literal
from urllib.parse import quote

from jointseg.exceptions import JobStateError
from jointseg.io import read_scan, write_scan
from jointseg.objects.ifc import write_ifc
from jointseg.objects.records import LayoutReport
from server.storage import ResultFormat, Storage

log = logging.getLogger(__name__)

#: What a finished job offers to download: the segmented scan (ply, las, laz), its report, its
#: objects and rooms (objects.json) and its IFC model.
Download = Literal["ply", "las", "laz", "report", "objects", "ifc"]
DOWNLOADS: tuple[Download, ...] = ("ply", "las", "laz", "report", "objects", "ifc")

_locks: dict[Path, threading.Lock] = {}
_locks_guard = threading.Lock()


def _lock_for(path: Path) -> threading.Lock:
    with _locks_guard:
        return _locks.setdefault(path, threading.Lock())


@contextlib.contextmanager
def lock_for(path: Path) -> Iterator[None]:
    """Hold this process's lock of ``path`` (one file made once however many ask at once)."""
    with _lock_for(path):
        yield
    with _locks_guard:
        _locks.pop(path, None)


def download_name(filename: str, kind: Download, version: int = 0) -> str:
    """The name a download of ``kind`` is saved under, from the uploaded file's name
    (``office.e57`` gives ``office_segmented.laz``, ``office_report.json``, ``office.ifc``);
    a corrected labels version says which (``office_segmented_v2.laz``, ``office_v2.ifc``)."""
    stem = filename.rsplit(".", 1)[0] or "result"
    tag = f"_v{int(version)}" if version else ""
    if kind == "report":
        return f"{stem}_report{tag}.json"
    if kind == "objects":
        return f"{stem}_objects{tag}.json"
    if kind == "ifc":
        return f"{stem}{tag}.ifc"
    return f"{stem}_segmented{tag}.{kind}"


def content_disposition(name: str, disposition: str = "attachment") -> str:
    """A ``Content-Disposition`` value naming ``name`` (RFC 6266 ``filename*`` when the name is
    not plain ASCII), as Starlette's FileResponse writes it."""
    quoted = quote(name)
    if quoted != name:
        return f"{disposition}; filename*=utf-8''{quoted}"
    return f'{disposition}; filename="{name}"'


def layout_from(report: Path) -> LayoutReport:
    """The objects, rooms and walls a report.json holds.

    Raises
    ------
    JobStateError
        When the run found no objects or rooms.
    """
    return LayoutReport.from_report(json.loads(report.read_text(encoding="utf-8")))


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
    return layout_from(path)


def convert_result(
    result: Path, report: Path | None, target: Path, fmt: ResultFormat, *, name: str
) -> Path:
    """``target``: the scan ``result`` written as ``fmt`` (ply, las, laz), or for ``ifc`` the IFC
    model of ``report`` (named ``name``); made once, under a lock, and kept.

    Raises
    ------
    JobStateError
        For ``ifc`` without a report, or when the run found no objects or rooms.
    """
    if target.is_file():
        return target
    with lock_for(target):
        if not target.is_file() and fmt == "ifc":
            if report is None or not report.is_file():
                raise JobStateError(f"job {name} has no report")
            write_ifc(layout_from(report), target, name=name)
            log.info("job %s: IFC model written", name)
        elif not target.is_file():
            write_scan(read_scan(result, max_points=1 << 40), target)
            log.info("job %s: result converted to %s", name, fmt)
    return target


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
    return convert_result(ply, storage.report_path(job_id), target, fmt, name=job_id)
