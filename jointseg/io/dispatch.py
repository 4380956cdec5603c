"""A path checked and its format picked, shared by whole-scan and chunked reading and writing.

:mod:`jointseg.io` and :mod:`jointseg.io.stream` both start here, so a missing file, a bad
``max_points`` or an unwritable target is refused with the same message by either.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

from jointseg.exceptions import ConfigError, ScanFormatError
from jointseg.io.formats import detect_format, writer_for
from jointseg.io.limits import check_input_file
from jointseg.progress import ProgressFn
from jointseg.scan import Scan


def prepare_input(path: str | os.PathLike[str], max_points: int) -> tuple[Path, str]:
    """The input as a Path and its format name, after checking ``max_points`` and the file.

    Raises
    ------
    ConfigError
        When ``max_points`` is not positive.
    ScanFormatError
        For a missing, empty or unknown input (see :func:`jointseg.io.limits.check_input_file`).
    """
    path = Path(path)
    if max_points < 1:
        raise ConfigError(f"max_points must be a positive integer, got {max_points}")
    if not path.exists():
        raise ScanFormatError(f"{path}: file not found")
    fmt = detect_format(path)
    if fmt != "s3dis":
        check_input_file(path)
    return path, fmt


def prepare_output(path: Path) -> Callable[[Scan, Path, ProgressFn | None], None]:
    """The writer for ``path``, after checking that a file can be written there.

    Raises
    ------
    ScanFormatError
        For an extension that cannot be written, a target that is a folder, or a missing folder.
    """
    write = writer_for(path)
    if path.is_dir():
        raise ScanFormatError(f"{path}: is a directory; give a file name to write to")
    if not path.parent.is_dir():
        raise ScanFormatError(f"{path}: folder {path.parent} does not exist")
    return write
