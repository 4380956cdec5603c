"""Where a job's files live, and how they are written so no half-written file is ever visible.

Layout of the data directory::

    jobs/<job id>/input.<ext>     the upload, under a fixed name (the user's name is in the job row)
    jobs/<job id>/result.ply      what `jointseg segment` writes (result.las / .laz on request)
    jobs/<job id>/report.json     the report of `jointseg segment --report`
    jobs/<job id>/labels/v<n>.npy
                                  labels version n's user classes (int16, -1 none; n >= 1)
    jobs/<job id>/labels/v<n>/    its files (result.ply/.las/.laz, objects.json, report.json,
                                  result.ifc), made on the first request and kept
    jobs/<model id>/model.pt      a model learnt from corrected jobs (POST /v1/models): its
                                  id is a job row's (server.state.model_jobs)
    jobs/<job id>/tiles/<n>/      a tiled job's work folder while it runs, per attempt of its
                                  plan (spilled scan, tile results: jointseg.pipeline.tile_store);
                                  removed when the job ends
    incoming/api-<host>-<pid>-<n>/
                                  uploads still streaming into one API process (temporary
                                  names), beside its .lock file, locked while it runs

Every file appears by rename after an fsync (:mod:`jointseg.io.atomic`), and job ids are checked
to be 32 hex digits before they become part of a path.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import re
import secrets
import shutil
import socket
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
        self._uploads_dir: Path | None = None  # this API process's folder in incoming/
        self._uploads_lock: int | None = None  # its lock file, held while the process runs

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

    def model_path(self, model_id: str) -> Path:
        """A model's checkpoint (``model.pt``; it exists once the model succeeded)."""
        return self.job_dir(model_id) / "model.pt"

    def labels_dir(self, job_id: str) -> Path:
        """The folder of a job's labels versions (not created)."""
        return self.job_dir(job_id) / "labels"

    def labels_path(self, job_id: str, version: int) -> Path:
        """Labels version ``version``'s user classes per point (``v<n>.npy``; may not exist)."""
        return self.labels_dir(job_id) / f"v{int(version)}.npy"

    def version_dir(self, job_id: str, version: int) -> Path:
        """The files of labels version ``version`` (``v<n>/``; not created)."""
        return self.labels_dir(job_id) / f"v{int(version)}"

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
        folder = self._uploads_dir or self.incoming_dir
        fd, name = tempfile.mkstemp(prefix="upload-", suffix=suffix.lower(), dir=folder)
        os.close(fd)
        return Path(name)

    def claim_incoming(self) -> int:
        """Give this API process an uploads folder of its own in ``incoming/``, and remove
        those of API processes that have ended; returns how many were removed.

        Why: an upload cut short by a crash (even a SIGKILL) can never finish, so a restart
        removes it at once, but another API sharing the data directory (several APIs behind a
        load balancer, see the many-machines guide) may be receiving uploads right now. Each
        API holds an exclusive ``flock`` on its folder's ``.lock`` file for as long as it runs
        (the kernel drops it when the process dies, however it dies); a folder whose lock can
        be taken has no living owner. On NFS this relies on the server's lock support
        (NFSv4, or lockd for v3).
        """
        removed = 0
        for lock in sorted(self.incoming_dir.glob("api-*.lock")):
            with contextlib.suppress(OSError):
                fd = os.open(lock, os.O_RDWR)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:  # its API is running
                    continue
                finally:
                    # closing drops the lock; an API taking this name meanwhile is impossible
                    # (names carry a random part), so the folder stays ownerless
                    os.close(fd)
                shutil.rmtree(self.incoming_dir / lock.stem, ignore_errors=True)
                lock.unlink(missing_ok=True)
                removed += 1
                log.info("removed the unfinished uploads of an ended API (%s)", lock.stem)
        host = re.sub(r"[^A-Za-z0-9-]", "_", socket.gethostname())[:64]
        name = f"api-{host}-{os.getpid()}-{secrets.token_hex(4)}"
        lock = self.incoming_dir / f"{name}.lock"
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        folder = self.incoming_dir / name
        folder.mkdir()
        self._uploads_dir, self._uploads_lock = folder, fd
        return removed

    def release_incoming(self) -> None:
        """Remove this API process's uploads folder (what streams into it now is abandoned)
        and drop its lock: the end of :meth:`claim_incoming`."""
        folder, fd = self._uploads_dir, self._uploads_lock
        self._uploads_dir = self._uploads_lock = None
        if folder is None or fd is None:
            return
        shutil.rmtree(folder, ignore_errors=True)
        (folder.parent / f"{folder.name}.lock").unlink(missing_ok=True)
        os.close(fd)

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
        """Remove what lies loose in ``incoming/`` for longer than ``older_than_s`` (uploads
        of an older version, folders a crash left half deleted); returns how many. The API
        processes' own folders are :meth:`claim_incoming`'s."""
        cutoff = time.time() - older_than_s
        removed = 0
        for path in self.incoming_dir.iterdir():
            if path.name.startswith("api-"):
                continue
            with contextlib.suppress(OSError):
                if path.stat().st_mtime < cutoff:
                    if path.is_dir():
                        shutil.rmtree(path, ignore_errors=True)
                    else:
                        path.unlink()
                    removed += 1
        return removed
