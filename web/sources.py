"""Where the viewer finds finished jobs: an interface, and a folder of result files.

The viewer only needs a list of finished jobs (newest first) and a few paths per job, so it
runs the same on the job service's storage (:mod:`web.service_source`) and on a plain folder
(tests, or looking at results of ``jointseg segment`` without the service).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from pydantic import BaseModel, ConfigDict

from jointseg.exceptions import JobNotFound, JobStateError
from server.results import convert_result
from server.storage import ResultFormat

if TYPE_CHECKING:
    from jointseg.labels.edits import EditList

#: File types a folder source lists as results.
RESULT_SUFFIXES = (".ply", ".las", ".laz")


class JobEntry(BaseModel):
    """One finished job as the job picker lists it."""

    model_config = ConfigDict(frozen=True)

    id: str
    filename: str
    created_at: datetime | None = None
    points: int | None = None

    @property
    def label(self) -> str:
        """The picker's text for this job: file name, short id and creation time."""
        when = "" if self.created_at is None else self.created_at.strftime(" %Y-%m-%d %H:%M")
        return f"{self.filename} [{self.id[:8]}]{when}"


@dataclass(frozen=True)
class LabelsInfo:
    """Which labels version of a job the viewer shows, and whether it can save a new one.

    ``etag`` is what a save sends as ``If-Match``; ``refusal`` says why this source cannot
    save (None: it can).
    """

    version: int = 0
    etag: str | None = None
    corrected: int = 0
    refusal: str | None = None


#: Why a folder of results keeps no versions (the viewer shows it instead of saving).
FOLDER_REFUSAL = (
    "A folder of results keeps no label versions: open the job through `jointseg serve` to "
    "save, or correct the file with `jointseg relabel --edits`."
)


class JobSource(Protocol):
    """What the viewer reads finished jobs from."""

    def finished_jobs(self) -> Sequence[JobEntry]:
        """Jobs with a result, newest first."""
        ...

    def result_path(self, job_id: str) -> Path:
        """The job's result file; raises :class:`JobNotFound` for an unknown or unfinished job."""
        ...

    def report_path(self, job_id: str) -> Path | None:
        """The job's report.json, None when it has none."""
        ...

    def export_path(self, job_id: str, fmt: ResultFormat) -> Path:
        """The job's result as ``fmt`` (ply, las, laz) or its IFC model (ifc), made on the
        first request; raises :class:`JobNotFound` as :meth:`result_path` does and
        :class:`jointseg.exceptions.JobStateError` when the run found no objects or rooms."""
        ...

    def labels(self, job_id: str) -> LabelsInfo:
        """The labels version :meth:`result_path` holds, and its ETag."""
        ...

    def save_edits(self, job_id: str, edits: EditList, *, if_match: str | None) -> LabelsInfo:
        """Save ``edits`` as a new labels version over the one ``if_match`` names; raises
        :class:`jointseg.exceptions.PreconditionFailed` when another save came first and
        :class:`jointseg.exceptions.JobStateError` when the source cannot save."""
        ...


class DirectorySource:
    """Every result file in a folder is a finished job; its id is the file name's stem.

    ``<id>.report.json`` (or ``<id>.json``) beside a result is its report. Conversions for
    downloads are made in a temporary folder of the source's own, never beside the results
    (a LAS written there would be listed as another job).
    """

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)
        self._exports: tempfile.TemporaryDirectory[str] | None = None  # made on first use

    def finished_jobs(self) -> list[JobEntry]:
        """Result files, newest first by modification time."""
        files = [
            p
            for p in self.folder.iterdir()
            if p.is_file() and p.suffix.lower() in RESULT_SUFFIXES and not p.name.startswith(".")
        ]
        stamped = sorted(((p.stat().st_mtime, p) for p in files), reverse=True)
        return [
            JobEntry(
                id=p.stem,
                filename=p.name,
                created_at=datetime.fromtimestamp(mtime, tz=UTC),
            )
            for mtime, p in stamped
        ]

    def result_path(self, job_id: str) -> Path:
        """The result file of ``job_id``."""
        if Path(job_id).name != job_id or job_id.startswith("."):
            raise JobNotFound(f"no finished job {job_id!r}")
        for suffix in RESULT_SUFFIXES:
            path = self.folder / f"{job_id}{suffix}"
            if path.is_file():
                return path
        raise JobNotFound(f"no finished job {job_id!r} in {self.folder}")

    def report_path(self, job_id: str) -> Path | None:
        """``<id>.report.json`` or ``<id>.json`` beside the result, if present."""
        for name in (f"{job_id}.report.json", f"{job_id}.json"):
            path = self.folder / name
            if path.is_file():
                return path
        return None

    def export_path(self, job_id: str, fmt: ResultFormat) -> Path:
        """The result as ``fmt``: the file itself when it is one, else a conversion (or the
        report's IFC model) kept in the source's temporary folder."""
        result = self.result_path(job_id)
        if result.suffix.lower() == f".{fmt}":
            return result
        if self._exports is None:
            self._exports = tempfile.TemporaryDirectory(prefix="jointseg-view-")
        target = Path(self._exports.name) / f"{job_id}.{fmt}"
        return convert_result(result, self.report_path(job_id), target, fmt, name=job_id)

    def labels(self, job_id: str) -> LabelsInfo:
        """A file of a folder is always its own version 0, and cannot be saved over."""
        self.result_path(job_id)
        return LabelsInfo(refusal=FOLDER_REFUSAL)

    def save_edits(self, job_id: str, edits: EditList, *, if_match: str | None) -> LabelsInfo:
        """Refused: results in a folder are other programs' files (:data:`FOLDER_REFUSAL`)."""
        raise JobStateError(FOLDER_REFUSAL)
