"""Where a job's files live, and how they are written so no half-written file is ever visible.

Layout of the data directory::

    jobs/<job id>/input.<ext>     the upload, under a fixed name (the user's name is in the job row)
    jobs/<job id>/result.ply      what `jointseg segment` writes (result.las / .laz on request)
    jobs/<job id>/report.json     the report of `jointseg segment --report`
    jobs/<job id>/tiles/<n>/      a tiled job's work folder while it runs, per attempt of its
                                  plan (spilled scan, tile results: jointseg.pipeline.tile_store);
                                  removed when the job ends
    incoming/                     uploads still streaming (temporary names)

Every file appears by rename after an fsync (:mod:`jointseg.io.atomic`), and job ids are checked
to be 32 hex digits before they become part of a path.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import tempfile
import time
from pathlib import Path
from typing import Literal

from jointseg.exceptions import JobNotFound
from jointseg.io.atomic import atomic_open

log = logging.getLogger(__name__)

ResultFormat = Literal["ply", "las", "laz", "ifc"]
RESULT_FORMATS: tuple[ResultFormat, ...] = ("ply", "las", "laz", "ifc")
_JOB_ID = re.compile(r"^[0-9a-f]{32}$")


def check_job_id(job_id: str) -> str:
    """``job_id`` when it is 32 lowercase hex digits, else :class:`JobNotFound`."""
    if not _JOB_ID.fullmatch(job_id):
        raise JobNotFound(f"job {job_id!r} not found (ids are 32 hex digits)")
    return job_id


def _fsync_dir(directory: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


class Storage:
    """The files of every job under one data directory.

    Parameters
    ----------
    data_dir : Path
        Created when missing; shared by every API and worker process.
    """

    def __init__(self, data_dir: Path) -> None:
        self.root = Path(data_dir).resolve()
        self.jobs_dir = self.root / "jobs"
        self.incoming_dir = self.root / "incoming"
        self.jobs_dir.mkdir(parents=True, exist_ok=True)
        self.incoming_dir.mkdir(parents=True, exist_ok=True)

    def job_dir(self, job_id: str) -> Path:
        """The folder of one job (not created)."""
        return self.jobs_dir / check_job_id(job_id)

    def upload_path(self, job_id: str, suffix: str | None = None) -> Path:
        """The stored upload: ``input<suffix>``, or when no suffix is given the one that exists.

        Raises
        ------
        JobNotFound
            Without ``suffix``, when the job has no stored upload.
        """
        folder = self.job_dir(job_id)
        if suffix is not None:
            return folder / f"input{suffix.lower()}"
        found = sorted(folder.glob("input.*")) if folder.is_dir() else []
        if not found:
            raise JobNotFound(f"job {job_id}: no stored upload")
        return found[0]

    def result_path(self, job_id: str, fmt: ResultFormat = "ply") -> Path:
        """The result scan in ``fmt`` (ply, las or laz), or its IFC model (ifc); it may not exist
        yet."""
        if fmt not in RESULT_FORMATS:
            raise ValueError(f"result format must be one of {RESULT_FORMATS}, got {fmt!r}")
        return self.job_dir(job_id) / f"result.{fmt}"

    def report_path(self, job_id: str) -> Path:
        """The job's report.json; it may not exist yet."""
        return self.job_dir(job_id) / "report.json"

    def tiles_dir(self, job_id: str, attempt: int | None = None) -> Path:
        """The tile folders of a job, or the work folder of its plan's attempt ``attempt``
        (:mod:`jointseg.pipeline.tile_store`; not created)."""
        folder = self.job_dir(job_id) / "tiles"
        return folder if attempt is None else folder / str(int(attempt))

    def remove_tiles(self, job_id: str) -> bool:
        """Remove a tiled job's work folder; returns whether there was one."""
        folder = self.tiles_dir(job_id)
        if not folder.exists():
            return False
        # renamed first, so a new plan can start at once and nobody sees half a folder
        trash = self.incoming_dir / f"tiles-{job_id}-{os.getpid()}-{time.monotonic_ns()}"
        try:
            os.replace(folder, trash)
        except FileNotFoundError:  # another process removed it meanwhile
            return False
        shutil.rmtree(trash, ignore_errors=True)
        log.info("removed the tile folder of job %s", job_id)
        return True

    def new_incoming(self, suffix: str) -> Path:
        """An empty temporary file for an upload that is still streaming.

        The name keeps ``suffix`` so the readers recognise the format; move it into place with
        :meth:`commit_upload`, or unlink it.
        """
        fd, name = tempfile.mkstemp(prefix="upload-", suffix=suffix.lower(), dir=self.incoming_dir)
        os.close(fd)
        return Path(name)

    def commit_upload(self, tmp: Path, job_id: str, suffix: str) -> Path:
        """Fsync an upload received by :meth:`incoming` and rename it to the job's input."""
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        target = self.upload_path(job_id, suffix)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, target)
        _fsync_dir(target.parent)
        return target

    def write_bytes(self, path: Path, data: bytes) -> None:
        """Write a small file atomically (temporary name, fsync, rename)."""
        with atomic_open(path) as fh:
            fh.write(data)

    def delete(self, job_id: str) -> None:
        """Remove every file of the job (nothing happens when there are none)."""
        folder = self.job_dir(job_id)
        if folder.exists():
            # rename first, so a reader sees the whole folder or none of it
            trash = self.incoming_dir / f"deleted-{job_id}-{os.getpid()}-{time.monotonic_ns()}"
            os.replace(folder, trash)
            shutil.rmtree(trash, ignore_errors=True)
            log.info("deleted the files of job %s", job_id)

    def clean_incoming(self, *, older_than_s: float = 3600.0) -> int:
        """Remove uploads abandoned mid-stream (a crashed API); returns how many."""
        cutoff = time.time() - older_than_s
        removed = 0
        for path in self.incoming_dir.iterdir():
            with contextlib.suppress(OSError):
                if path.stat().st_mtime < cutoff:
                    if path.is_dir():
                        shutil.rmtree(path, ignore_errors=True)
                    else:
                        path.unlink()
                    removed += 1
        return removed
