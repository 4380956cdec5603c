"""NumPy files: ``.npy`` tables and ``.npz`` archives (loaded with ``allow_pickle=False``).

An ``.npy`` file holds an (N, C) numeric array whose columns mean what they mean in a text
point list (3 = x y z, 4 = x y z intensity, 6 = x y z r g b, 7 = x y z r g b label).

An ``.npz`` archive holds ``xyz`` (N, 3), optionally ``rgb`` (N, 3) and ``labels`` (N,), and any
other per-point array as a field of the same name, dtype and shape (2-D fields stay 2-D). It is
the lossless format: writing then reading gives back exactly the same scan.
"""

from __future__ import annotations

import logging
import math
import zipfile
from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError, library_reason
from jointseg.io.atomic import atomic_open
from jointseg.io.build import build_scan
from jointseg.io.colour import to_rgb8
from jointseg.io.formats.text import POSITIONAL_COLUMNS, columns_to_parts
from jointseg.io.labels import normalise_labels
from jointseg.io.limits import (
    DEFAULT_MAX_INFLATION,
    ScanInfo,
    check_inflation,
    check_max_points,
)
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

_NPZ_KEYS = ("xyz", "rgb", "labels")


def _read_npy_header(fh, path: Path, what: str) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype from an .npy header without reading the data."""
    try:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
        else:
            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
    except (ValueError, OSError, EOFError) as exc:
        raise ScanFormatError(
            f"{path}: {what} is not a valid .npy array: {library_reason(exc)}"
        ) from exc
    return shape, dtype


def _check_npy_table(shape: tuple[int, ...], dtype: np.dtype, path: Path) -> None:
    if dtype.kind not in "iufb" or len(shape) != 2 or shape[1] not in POSITIONAL_COLUMNS:
        raise ScanFormatError(
            f"{path}: expected a numeric (N, 3|4|6|7) array (x y z [intensity | r g b [label]]), "
            f"got shape {shape} of dtype {dtype}"
        )


def read_npy(path: Path, *, max_points: int, progress: ProgressFn | None = None) -> Scan:
    """Read an (N, 3|4|6|7) ``.npy`` table.

    Parameters
    ----------
    path : Path
    max_points : int
        Refuse arrays with more rows (checked from the header).
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    Scan

    Raises
    ------
    ScanFormatError
        On a file that is not .npy, a wrong shape or dtype, a truncated array, non-finite
        coordinates or too many rows.
    """
    probe_npy(path, max_points=max_points)  # magic, shape, dtype, size and max_points
    report(progress, "read", 0.0)
    try:
        table = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise ScanFormatError(
            f"{path}: cannot load the array (truncated file?): {library_reason(exc)}"
        ) from exc
    xyz, rgb, labels, fields = columns_to_parts(table, None, path=path)
    report(progress, "read", 1.0)
    return build_scan(path, "npy", xyz, rgb, labels, fields, locate=lambda i: f"row {i}")


def probe_npy(path: Path, *, max_points: int) -> ScanInfo:
    """Check an ``.npy`` header (magic, shape, dtype, size) without loading the data.

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
        On a bad header, shape or dtype, or too many rows.
    """
    with open(path, "rb") as fh:
        shape, dtype = _read_npy_header(fh, path, "the file")
        data_start = fh.tell()
    _check_npy_table(shape, dtype, path)
    check_max_points(shape[0], max_points, path)
    need = int(np.prod(shape)) * dtype.itemsize
    have = path.stat().st_size - data_start
    if have < need:
        raise ScanFormatError(
            f"{path}: truncated .npy: the header declares shape {shape} ({need:,} bytes) but only "
            f"{have:,} bytes of data follow"
        )
    cols = POSITIONAL_COLUMNS[shape[1]]
    return ScanInfo(
        path=str(path),
        format="npy",
        n_points=shape[0],
        has_rgb="red" in cols,
        has_labels="label" in cols,
        fields=("intensity",) if "intensity" in cols else (),
    )


def _npz_headers(
    path: Path, max_inflation: float = DEFAULT_MAX_INFLATION
) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Each array's shape and dtype, after checking what the archive declares against its size.

    A member's .npy header must fit the uncompressed size the zip declares for it (zipfile
    never inflates a member beyond that), and all members together may inflate to at most
    ``max_inflation`` times the archive: a 0.5 MB archive of zeros that inflates to 480 MB is
    refused here, before any array is allocated.
    """
    try:
        with zipfile.ZipFile(path) as zf:
            out = {}
            declared = 0
            for info in zf.infolist():
                declared += info.file_size
                if not info.filename.endswith(".npy"):
                    continue
                with zf.open(info) as fh:
                    shape, dtype = _read_npy_header(fh, path, f"member {info.filename!r}")
                    need = math.prod(shape) * dtype.itemsize
                    if need > info.file_size - fh.tell():
                        raise ScanFormatError(
                            f"{path}: member {info.filename!r} declares shape {shape} "
                            f"({need:,} bytes) but holds only {info.file_size:,} bytes"
                        )
                out[info.filename[:-4]] = (shape, dtype)
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise ScanFormatError(f"{path}: not a valid .npz archive: {library_reason(exc)}") from exc
    points = f" of {out['xyz'][0][0]:,} points" if out.get("xyz", ((),))[0] else ""
    check_inflation(
        declared,
        path.stat().st_size,
        max_inflation,
        path,
        what=f"the .npz archive's {len(out)} arrays{points}",
    )
    return out


def _check_npz_headers(
    headers: dict[str, tuple[tuple[int, ...], np.dtype]], path: Path, max_points: int
) -> int:
    if "xyz" not in headers:
        raise ScanFormatError(
            f"{path}: .npz has no 'xyz' array (found: {', '.join(sorted(headers)) or 'none'})"
        )
    shape, dtype = headers["xyz"]
    if len(shape) != 2 or shape[1] != 3 or dtype.kind not in "iuf":
        raise ScanFormatError(f"{path}: 'xyz' must be a numeric (N, 3) array, got {shape} {dtype}")
    n = shape[0]
    check_max_points(n, max_points, path)
    for key, (kshape, kdtype) in headers.items():
        if key == "xyz":
            continue
        if kdtype.kind not in "iufb" or not kshape or kshape[0] != n or len(kshape) > 2:
            raise ScanFormatError(
                f"{path}: array {key!r} must be numeric with {n} rows (one per point) and 1 or 2 "
                f"dimensions, got shape {kshape} of dtype {kdtype}"
            )
    if "rgb" in headers and headers["rgb"][0] != (n, 3):
        raise ScanFormatError(f"{path}: 'rgb' must have shape ({n}, 3), got {headers['rgb'][0]}")
    if "labels" in headers and headers["labels"][0] != (n,):
        raise ScanFormatError(
            f"{path}: 'labels' must have shape ({n},), got {headers['labels'][0]}"
        )
    return n


def read_npz(
    path: Path,
    *,
    max_points: int,
    max_inflation: float = DEFAULT_MAX_INFLATION,
    progress: ProgressFn | None = None,
) -> Scan:
    """Read an ``.npz`` archive with ``xyz``, optional ``rgb`` / ``labels`` and fields.

    Parameters
    ----------
    path : Path
    max_points : int
        Refuse archives whose ``xyz`` has more rows (checked from its header).
    max_inflation : float
        Refuse archives whose arrays inflate to more than this many times the file.
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    Scan

    Raises
    ------
    ScanFormatError
        On a file that is not a zip of .npy arrays, a missing ``xyz``, arrays of the wrong shape
        or dtype (object arrays are refused), an archive inflating beyond ``max_inflation``,
        non-finite coordinates or too many points.
    """
    headers = _npz_headers(path, max_inflation)
    _check_npz_headers(headers, path, max_points)
    report(progress, "read", 0.0)
    arrays: dict[str, np.ndarray] = {}
    try:
        with np.load(path, allow_pickle=False) as npz:
            for i, key in enumerate(headers):
                arrays[key] = npz[key]
                report(progress, "read", (i + 1) / len(headers))
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ScanFormatError(
            f"{path}: cannot load the arrays (truncated file?): {library_reason(exc)}"
        ) from exc
    xyz = arrays.pop("xyz")
    rgb = arrays.pop("rgb", None)
    if rgb is not None:
        rgb = to_rgb8(rgb, path=path, what="'rgb'")
    raw_labels = arrays.pop("labels", None)
    labels = None
    if raw_labels is not None:
        labels, extra = normalise_labels(raw_labels, path=path, source="labels")
        arrays.update(extra)
    return build_scan(path, "npz", xyz, rgb, labels, arrays)


def probe_npz(
    path: Path, *, max_points: int, max_inflation: float = DEFAULT_MAX_INFLATION
) -> ScanInfo:
    """Check the array headers inside an ``.npz`` archive without loading the data.

    Parameters
    ----------
    path : Path
    max_points : int
    max_inflation : float

    Returns
    -------
    ScanInfo

    Raises
    ------
    ScanFormatError
        As :func:`read_npz`, for what the headers show.
    """
    headers = _npz_headers(path, max_inflation)
    n = _check_npz_headers(headers, path, max_points)
    return ScanInfo(
        path=str(path),
        format="npz",
        n_points=n,
        has_rgb="rgb" in headers,
        has_labels="labels" in headers,
        fields=tuple(k for k in headers if k not in _NPZ_KEYS),
    )


def write_npz(scan: Scan, path: Path, *, progress: ProgressFn | None = None) -> None:
    """Write every part of the scan, dtypes and shapes unchanged, to an uncompressed ``.npz``.

    Parameters
    ----------
    scan : Scan
    path : Path
        Target file (written atomically).
    progress : ProgressFn, optional
        Receives ``("write", fraction)``.

    Raises
    ------
    ScanFormatError
        When a field is named ``xyz``, ``rgb`` or ``labels``, or is not numeric.
    """
    arrays: dict[str, np.ndarray] = {"xyz": scan.xyz}
    if scan.rgb is not None:
        arrays["rgb"] = scan.rgb
    if scan.labels is not None:
        arrays["labels"] = scan.labels
    for name, values in scan.fields.items():
        if name in _NPZ_KEYS:
            raise ScanFormatError(f"{path}: field name {name!r} is reserved in .npz files")
        if values.dtype.kind not in "iufb":
            raise ScanFormatError(f"{path}: field {name!r} has non-numeric dtype {values.dtype}")
        arrays[name] = values
    report(progress, "write", 0.0)
    with atomic_open(path) as fh:
        np.savez(fh, **arrays)  # type: ignore[arg-type]  # numpy's stub types allow_pickle
    report(progress, "write", 1.0)
