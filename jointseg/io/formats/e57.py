"""E57 (ASTM) through pye57, reading only: every scan in the file, posed and merged.

Each scan is read with its pose applied (``transform=True``), so scans of one project land in
one frame; spherical-only scans are converted to Cartesian by pye57; points flagged invalid are
dropped. Colour is kept when every scan has it, and intensity (a field) likewise. E57 holds no
labels. Writing E57 is not supported (pye57 stores float32 coordinates and no labels or
fields); convert to PLY, LAS, PCD or NPZ instead.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError, library_reason
from jointseg.io.build import build_scan
from jointseg.io.colour import to_rgb8
from jointseg.io.limits import (
    DEFAULT_MAX_INFLATION,
    ScanInfo,
    check_inflation,
    check_max_points,
)
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

_COLOUR = ("colorRed", "colorGreen", "colorBlue")
_CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
_SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")


def _reason(exc: BaseException) -> str:
    """What libE57Format says is wrong, without its debug block (the file's path on the server,
    C++ source paths, checksums) that follows on further lines."""
    return library_reason(exc)


def _open(path: Path):  # -> pye57.E57
    import pye57

    with open(path, "rb") as fh:
        magic = fh.read(8)
    if magic != b"ASTM-E57":
        raise ScanFormatError(f"{path}: not an E57 file (it does not start with 'ASTM-E57')")
    try:
        return pye57.E57(str(path))
    except Exception as exc:  # libE57 raises its own exception types
        raise ScanFormatError(f"{path}: not a readable E57 file: {_reason(exc)}") from exc


def _scan_headers(e57, path: Path) -> list:
    try:
        headers = [e57.get_header(i) for i in range(e57.scan_count)]
    except Exception as exc:  # libE57 raises its own exception types
        raise ScanFormatError(f"{path}: cannot read the E57 scan headers: {_reason(exc)}") from exc
    if not headers:
        raise ScanFormatError(f"{path}: the E57 file contains no scans")
    for i, header in enumerate(headers):
        fields = set(header.point_fields)
        if not (set(_CARTESIAN) <= fields or set(_SPHERICAL) <= fields):
            raise ScanFormatError(
                f"{path}: E57 scan {i} has neither Cartesian nor spherical coordinates "
                f"(fields: {', '.join(sorted(fields))})"
            )
    return headers


#: Bytes a point takes once read (three float64 coordinates), for the inflation check.
_POINT_BYTES = 24


def _check_counts(path: Path, n: int, max_points: int, max_inflation: float) -> None:
    """The scans' declared count against max_points and the file's size (E57 packs values in
    as few bits as their range needs, so a lying count would otherwise allocate freely)."""
    check_max_points(n, max_points, path)
    check_inflation(
        n * _POINT_BYTES,
        path.stat().st_size,
        max_inflation,
        path,
        what=f"the E57 scans' {n:,} points",
    )


def probe_e57(
    path: Path, *, max_points: int, max_inflation: float = DEFAULT_MAX_INFLATION
) -> ScanInfo:
    """Sum the point counts of the scans in an E57 file without reading the points.

    Parameters
    ----------
    path : Path
    max_points : int

    Returns
    -------
    ScanInfo

    Raises
    ------
    ScanFormatError
        On a file that is not E57, no scans, scans without coordinates, or too many points.
    """
    e57 = _open(path)
    try:
        headers = _scan_headers(e57, path)
        n = sum(int(h.point_count) for h in headers)
        _check_counts(path, n, max_points, max_inflation)
        has_rgb = all(set(_COLOUR) <= set(h.point_fields) for h in headers)
        has_intensity = all("intensity" in h.point_fields for h in headers)
    finally:
        e57.close()
    return ScanInfo(
        path=str(path),
        format="e57",
        n_points=n,
        has_rgb=has_rgb,
        fields=("intensity",) if has_intensity else (),
    )


def read_e57(
    path: Path,
    *,
    max_points: int,
    max_inflation: float = DEFAULT_MAX_INFLATION,
    progress: ProgressFn | None = None,
) -> Scan:
    """Read and merge every scan of an E57 file in the file's common frame.

    Parameters
    ----------
    path : Path
    max_points : int
        Refuse files whose scans declare more points in all (checked before reading them).
    progress : ProgressFn, optional
        Receives ``("read", fraction)`` after each scan.

    Returns
    -------
    Scan
        ``fields`` holds ``intensity`` (float32) when every scan has it.

    Raises
    ------
    ScanFormatError
        On a file that is not E57, a corrupt file, no scans or too many points.
    """
    e57 = _open(path)
    try:
        headers = _scan_headers(e57, path)
        total = sum(int(h.point_count) for h in headers)
        _check_counts(path, total, max_points, max_inflation)
        has_rgb = all(set(_COLOUR) <= set(h.point_fields) for h in headers)
        has_intensity = all("intensity" in h.point_fields for h in headers)
        parts: list[dict[str, np.ndarray]] = []
        report(progress, "read", 0.0)
        for i in range(len(headers)):
            try:
                data = e57.read_scan(
                    i,
                    colors=has_rgb,
                    intensity=has_intensity,
                    ignore_missing_fields=True,
                    transform=True,
                )
            except Exception as exc:  # libE57 / pye57 raise their own types
                raise ScanFormatError(f"{path}: cannot read E57 scan {i}: {_reason(exc)}") from exc
            parts.append(data)
            report(progress, "read", (i + 1) / len(headers))
    finally:
        e57.close()
    xyz = np.concatenate(
        [np.stack([d[c] for c in _CARTESIAN], axis=1).astype(np.float64) for d in parts]
    )
    rgb = None
    if has_rgb:
        rgb = to_rgb8(
            np.concatenate([np.stack([d[c] for c in _COLOUR], axis=1) for d in parts]), path=path
        )
    elif any(set(_COLOUR) <= set(h.point_fields) for h in headers):
        logger.warning("%s: only some E57 scans have colour; colour is dropped", path)
    fields: dict[str, np.ndarray] = {}
    if has_intensity:
        fields["intensity"] = np.concatenate([d["intensity"] for d in parts]).astype(np.float32)
    return build_scan(path, "e57", xyz, rgb, None, fields)
