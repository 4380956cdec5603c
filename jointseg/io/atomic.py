"""Atomic file replacement, so a reader never sees a half-written scan.

Writers write to a temporary file in the target's directory, flush and fsync it, then rename it
over the target with :func:`os.replace`; on any error the temporary file is removed and the
target is left untouched.
"""

from __future__ import annotations

import contextlib
import logging
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

logger = logging.getLogger(__name__)


def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _fsync_dir(directory: Path) -> None:
    """Persist the rename itself (best effort; not every platform allows fsync on a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path next to ``path`` that replaces ``path`` when the block succeeds.

    For libraries that insist on opening the file themselves. The temporary name keeps the
    target's suffix, so libraries that look at the extension behave the same.

    Parameters
    ----------
    path : Path
        Final destination; its directory must exist.

    Yields
    ------
    Path
        Where to write.
    """
    path = Path(path)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{path.name}.", suffix=f".tmp{path.suffix}", dir=path.parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_current_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _fsync_dir(path.parent)
    logger.debug("wrote %s", path)


@contextlib.contextmanager
def atomic_open(path: Path) -> Iterator[BinaryIO]:
    """Yield a binary file object whose content replaces ``path`` when the block succeeds.

    Parameters
    ----------
    path : Path
        Final destination; its directory must exist.

    Yields
    ------
    BinaryIO
        Open for writing; flushed and fsynced before the rename.
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        yield fh
