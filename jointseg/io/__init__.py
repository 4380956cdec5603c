"""Reading and writing scans, so every stage works on one :class:`~jointseg.scan.Scan` type.

Formats (by extension): PLY, LAS/LAZ, E57 (read only), PCD, TXT/XYZ/CSV, NPY (read only), NPZ,
meshes (GLB/glTF, OBJ and PLY with faces; read only, as points sampled on the faces) and S3DIS
room folders (read only). Every problem with an input file is raised as
:class:`ScanFormatError` with a message naming the file and, where it can, the line, element or
field; nothing half-read is ever returned, and writes are atomic.

Examples
--------
>>> from jointseg.io import read_scan, write_scan      # doctest: +SKIP
>>> scan = read_scan("room.ply")                       # doctest: +SKIP
>>> write_scan(scan, "room.laz")                       # doctest: +SKIP
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from jointseg.exceptions import ScanFormatError, library_reason
from jointseg.io.dispatch import prepare_input, prepare_output
from jointseg.io.formats import READ_EXTENSIONS, WRITE_EXTENSIONS, detect_format, get_format
from jointseg.io.limits import DEFAULT_MAX_INFLATION, DEFAULT_MAX_POINTS, INPUT_ERRORS, ScanInfo
from jointseg.progress import ProgressFn
from jointseg.scan import Scan

__all__ = [
    "DEFAULT_MAX_INFLATION",
    "DEFAULT_MAX_POINTS",
    "READ_EXTENSIONS",
    "WRITE_EXTENSIONS",
    "ScanFormatError",
    "ScanInfo",
    "detect_format",
    "probe_scan",
    "read_scan",
    "write_scan",
]

logger = logging.getLogger(__name__)


def read_scan(
    path: str | os.PathLike[str],
    *,
    max_points: int = DEFAULT_MAX_POINTS,
    max_inflation: float = DEFAULT_MAX_INFLATION,
    progress: ProgressFn | None = None,
) -> Scan:
    """Read a scan file (or S3DIS room folder) of any supported format into a :class:`Scan`.

    Parameters
    ----------
    path : str or PathLike
        Scan file; the format comes from the extension (see ``READ_EXTENSIONS``), or a folder
        with ``Annotations/<class>_<n>.txt`` (S3DIS room).
    max_points : int
        Refuse scans with more points; checked from the header, before the body is read, where
        the format has one.
    max_inflation : float
        Refuse a compressed file (LAZ, NPZ, PCD, E57) whose header declares more than this many
        times its size; checked before anything is allocated or decompressed.
    progress : ProgressFn, optional
        Receives ``("read", fraction)`` as the file is read.

    Returns
    -------
    Scan
        ``source_format`` is set to the format name.

    Raises
    ------
    ScanFormatError
        For a missing, empty, truncated, malformed or too large input, an unknown extension,
        or non-finite coordinates; the message names the file and where it can the line,
        element or field.
    """
    path, fmt = prepare_input(path, max_points)
    logger.debug("reading %s as %s", path, fmt)
    entry = get_format(fmt)
    try:
        scan = entry.read(path, **entry.limits(max_points, max_inflation), progress=progress)
    except ScanFormatError:
        raise
    except INPUT_ERRORS as exc:
        raise ScanFormatError(f"{path}: cannot read as {fmt}: {library_reason(exc)}") from exc
    logger.info("read %s: %d points (%s)", path, len(scan), fmt)
    return scan


def probe_scan(
    path: str | os.PathLike[str],
    *,
    max_points: int = DEFAULT_MAX_POINTS,
    max_inflation: float = DEFAULT_MAX_INFLATION,
) -> ScanInfo:
    """Validate a scan's header and point count cheaply, without reading its points.

    Meant for refusing bad uploads before queuing work. Checks the format's magic and header,
    the body size against the declared count where the format allows (binary PLY/PCD,
    uncompressed LAS, NPY; compressed LAZ, NPZ, PCD and E57 against ``max_inflation``), and
    ``max_points``. Text formats are counted line by line.

    Parameters
    ----------
    path : str or PathLike
        As for :func:`read_scan`.
    max_points : int
        Refuse scans with more points.
    max_inflation : float
        As for :func:`read_scan`.

    Returns
    -------
    ScanInfo

    Raises
    ------
    ScanFormatError
        As :func:`read_scan`, for what can be seen without reading the points.
    """
    path, fmt = prepare_input(path, max_points)
    entry = get_format(fmt)
    try:
        return entry.probe(path, **entry.limits(max_points, max_inflation))
    except ScanFormatError:
        raise
    except INPUT_ERRORS as exc:
        raise ScanFormatError(f"{path}: cannot read as {fmt}: {library_reason(exc)}") from exc


def write_scan(
    scan: Scan, path: str | os.PathLike[str], *, progress: ProgressFn | None = None
) -> Path:
    """Write ``scan`` in the format named by the extension, atomically.

    The file appears complete or not at all: the data goes to a temporary file in the same
    folder, is flushed and fsynced, then renamed over ``path``.

    Parameters
    ----------
    scan : Scan
    path : str or PathLike
        Target; its extension picks the format (see ``WRITE_EXTENSIONS``) and its folder must
        exist.
    progress : ProgressFn, optional
        Receives ``("write", fraction)``.

    Returns
    -------
    Path
        The written file.

    Raises
    ------
    ScanFormatError
        For an extension that cannot be written, a missing folder, a target that is a folder, or
        a field the format cannot store.
    """
    path = Path(path)
    write = prepare_output(path)
    write(scan, path, progress)
    logger.info("wrote %s: %d points", path, len(scan))
    return path
