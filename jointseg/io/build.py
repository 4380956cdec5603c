"""The last step of every reader: arrays checked and assembled into a :class:`Scan`.

Each format module turns its file into plain arrays and hands them to :func:`build_scan`, so the
coordinate checks and their error wording live here once.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError
from jointseg.scan import RESERVED_FIELDS, Scan


def build_scan(
    path: Path,
    fmt: str,
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    fields: Mapping[str, np.ndarray] | None = None,
    *,
    locate: Callable[[int], str] | None = None,
    start: int | None = None,
) -> Scan:
    """Assemble the :class:`Scan` after checking what its constructor would reject, naming the file.

    Parameters
    ----------
    path : Path
        The file read, for messages.
    fmt : str
        Format name recorded as ``source_format``.
    xyz : ndarray of shape (N, 3), metres
    rgb : ndarray of shape (N, 3), uint8, optional
    labels : ndarray of shape (N,), int32, optional
    fields : dict of str to ndarray of shape (N,) or (N, k), optional
    locate : callable, optional
        Maps a point index to a human location (e.g. ``"line 12"``) for messages.
    start : int, optional
        When the arrays are one chunk of a file read in pieces: the index of its first point,
        so messages name points of the whole file.

    Returns
    -------
    Scan

    Raises
    ------
    ScanFormatError
        When there are no points or a coordinate is NaN or infinite.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.shape[0] == 0:
        raise ScanFormatError(f"{path}: the scan contains no points")
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.all():
        bad_rows = np.flatnonzero(~finite)
        bad = int(bad_rows[0])
        first = start or 0
        where = f"point {first + bad}" + (f" ({locate(bad)})" if locate is not None else "")
        among = (
            "in all"
            if start is None
            else f"among points {first}..{first + xyz.shape[0] - 1}, the chunk being read"
        )
        raise ScanFormatError(
            f"{path}: {where} has non-finite coordinates {xyz[bad].tolist()} "
            f"({bad_rows.size} such points {among}); coordinates must be finite numbers"
        )
    clean: dict[str, np.ndarray] = {}
    for name, values in (fields or {}).items():
        if name in RESERVED_FIELDS:
            name = f"{name}_field"
        clean[name] = values
    try:
        return Scan(xyz=xyz, rgb=rgb, labels=labels, fields=clean, source_format=fmt)
    except ScanFormatError as exc:
        raise ScanFormatError(f"{path}: {exc}") from exc
