"""Checking a stored upload in a separate process, so the API process never holds a scan.

Why: a header may lie (a 6 KB LAZ claiming 40 M points) and a small file may inflate (a 0.5 MB
NPZ of zeros holding 480 MB); reading either in the API took it to gigabytes, and a few at once
to the out-of-memory killer. The readers now refuse what a header declares beyond the file's
size (``max_inflation``) before allocating, and everything that reads an upload's bytes (the
probe, and the full read of small uploads) runs in a small pool of spawned checking processes:
whatever a hostile file costs is paid there, and a checker that dies is replaced.
"""

from __future__ import annotations

import logging
import os
import signal
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from jointseg.exceptions import JointsegError, ScanFormatError
from jointseg.io import ScanInfo, probe_scan
from jointseg.io.formats.mesh.core import check_single_file
from server.lifeline import die_with_parent
from server.limits import check_file_span
from server.messages import public_message
from server.settings import Settings

log = logging.getLogger(__name__)

#: Checking processes: uploads beyond this many wait for one (each may read a 64 MiB file).
CHECK_PROCESSES = 2
#: Checks a process runs before it is replaced (gives back what a large read left behind).
CHECKS_PER_PROCESS = 50


class CheckLimits(BaseModel):
    """The settings a check needs, sent to the checking process."""

    model_config = ConfigDict(frozen=True)

    max_points: int
    max_inflation: float
    max_span: float
    full_check_max_bytes: int

    @classmethod
    def of(cls, settings: Settings) -> CheckLimits:
        """The limits of ``settings``."""
        return cls(
            max_points=settings.max_points,
            max_inflation=settings.max_inflation,
            max_span=settings.max_span,
            full_check_max_bytes=settings.full_check_max_bytes,
        )


def check_upload_file(path: str, filename: str, size: int, limits: CheckLimits) -> ScanInfo:
    """Validate a stored upload: header and point count, and every point when small enough.

    Runs in a checking process. A glTF whose buffers or textures are files beside it is
    refused (an upload is one file, and it may not read other files on the server).

    Raises
    ------
    JointsegError
        With the reader's message, the temporary name replaced by the client's file name.
    """
    stored = Path(path)
    try:
        check_single_file(stored)
        info = probe_scan(stored, max_points=limits.max_points, max_inflation=limits.max_inflation)
        if size <= limits.full_check_max_bytes:
            check_file_span(
                stored,
                filename,
                limits.max_span,
                limits.max_points,
                max_inflation=limits.max_inflation,
            )
    except JointsegError as exc:
        raise type(exc)(public_message(exc, stored, filename)) from None
    return info.model_copy(update={"path": filename})


def _ready() -> None:
    """Run once in a new checking process (imports done, nothing else)."""


def _start_checker(parent_pid: int) -> None:
    """The pool's initializer: a checking process dies with the API (:mod:`server.lifeline`).

    Only the watchdog, no PR_SET_PDEATHSIG: the pool starts its processes from request
    threads, whose exit would fire it.
    """
    die_with_parent(parent_pid, sig=signal.SIGKILL, kernel=False)


class UploadChecker:
    """The pool of checking processes, started on first use and replaced when one dies."""

    def __init__(self, settings: Settings) -> None:
        self.limits = CheckLimits.of(settings)
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None
        self._closed = False

    def _executor(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._closed:
                raise RuntimeError("the upload checker is closed")
            if self._pool is None:
                self._pool = ProcessPoolExecutor(
                    max_workers=CHECK_PROCESSES,
                    mp_context=get_context("spawn"),
                    max_tasks_per_child=CHECKS_PER_PROCESS,
                    initializer=_start_checker,
                    initargs=(os.getpid(),),
                )
            return self._pool

    def warm(self) -> None:
        """Start one checking process now, so the first upload does not wait for it."""
        self._executor().submit(_ready)

    def check(self, path: Path, filename: str, size: int) -> ScanInfo:
        """Check a stored upload in a checking process (blocking: call from a thread).

        Raises
        ------
        JointsegError
            As :func:`check_upload_file`; ScanFormatError when the checking process died
            (e.g. killed for memory) on this file.
        """
        pool = self._executor()
        future = pool.submit(check_upload_file, str(path), filename, size, self.limits)
        try:
            return future.result()
        except BrokenProcessPool as exc:
            self._replace(pool)
            log.warning("a checking process died on upload %s: %s", filename, exc)
            raise ScanFormatError(
                f"{filename}: the file could not be checked (its checking process died, e.g. "
                f"out of memory)"
            ) from exc

    def _replace(self, broken: ProcessPoolExecutor) -> None:
        with self._lock:
            if self._pool is broken:
                self._pool = None
        broken.shutdown(wait=False, cancel_futures=True)

    def close(self) -> None:
        """Stop the checking processes (a check in progress is abandoned)."""
        with self._lock:
            pool, self._pool, self._closed = self._pool, None, True
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
