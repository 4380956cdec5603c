"""Checks and conversions shared by every scan reader and writer.

Each format module turns its file into plain arrays and hands them to :func:`build_scan`, so the
rules for colour scaling, label normalisation, coordinate checks and error wording live here once.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict

from jointseg.classes import NUM_CLASSES, UNLABELLED
from jointseg.exceptions import ScanFormatError
from jointseg.scan import RESERVED_FIELDS, Scan

logger = logging.getLogger(__name__)

#: Default upper bound on the number of points a reader accepts.
DEFAULT_MAX_POINTS: int = 50_000_000

#: Property / column names (lower case) read as ground-truth labels, in order of preference.
LABEL_NAMES: tuple[str, ...] = (
    "label",
    "class",
    "classification",
    "scalar_classification",
    "scalar_label",
)

#: Accepted spellings of the three colour channels (lower case), in order of preference.
COLOUR_NAMES: tuple[tuple[str, str, str], ...] = (
    ("red", "green", "blue"),
    ("r", "g", "b"),
    ("diffuse_red", "diffuse_green", "diffuse_blue"),
)


class ScanInfo(BaseModel):
    """What a cheap look at a scan file found, so uploads can be refused before any work is queued.

    Attributes
    ----------
    path : str
        The file or folder that was probed.
    format : str
        Format name as returned by :func:`jointseg.io.detect_format`.
    n_points : int
        Number of points: from the header where the format has one, else counted lines.
    has_rgb : bool
        Whether colour is present.
    has_labels : bool
        Whether ground-truth labels are present (for LAS: a classification dimension whose values
        are not all 0).
    fields : tuple of str
        Names of the other per-point attributes found (as :attr:`Scan.fields` would name them,
        as far as the header tells).
    """

    model_config = ConfigDict(frozen=True)

    path: str
    format: str
    n_points: int
    has_rgb: bool = False
    has_labels: bool = False
    fields: tuple[str, ...] = ()


def check_max_points(n_points: int, max_points: int, path: Path, *, what: str = "") -> None:
    """Refuse a scan larger than ``max_points`` before its body is read.

    Parameters
    ----------
    n_points : int
        Point count found (from the header, or counted).
    max_points : int
        The limit given to the reader.
    path : Path
        The file, for the message.
    what : str
        Optional qualifier for the count (e.g. ``"at least "``).

    Raises
    ------
    ScanFormatError
        When ``n_points > max_points``.
    """
    if n_points > max_points:
        raise ScanFormatError(
            f"{path}: the scan has {what}{n_points:,} points, more than max_points={max_points:,}; "
            f"pass a larger max_points (e.g. max_points={n_points}) to read it, or subsample the "
            f"scan first"
        )


def check_input_file(path: Path) -> None:
    """Fail early, with a plain message, on a missing file, a directory or an empty file.

    Parameters
    ----------
    path : Path
        Path expected to name a readable, non-empty regular file.

    Raises
    ------
    ScanFormatError
        When the file does not exist, is a directory or has 0 bytes.
    """
    if not path.exists():
        raise ScanFormatError(f"{path}: file not found")
    if path.is_dir():
        raise ScanFormatError(f"{path}: is a directory, expected a {path.suffix or 'scan'} file")
    if path.stat().st_size == 0:
        raise ScanFormatError(f"{path}: file is empty (0 bytes)")


def pick_name(names: list[str], candidates: tuple[str, ...]) -> str | None:
    """Return the first of ``names`` matching ``candidates`` case-insensitively, by preference."""
    lower = {n.lower(): n for n in reversed(names)}
    for cand in candidates:
        if cand in lower:
            return lower[cand]
    return None


def pick_colour_names(names: list[str]) -> tuple[str, str, str] | None:
    """Find the three colour channel names among ``names`` (case-insensitive), or None."""
    lower = {n.lower(): n for n in reversed(names)}
    for triple in COLOUR_NAMES:
        if all(c in lower for c in triple):
            return (lower[triple[0]], lower[triple[1]], lower[triple[2]])
    return None


def to_rgb8(channels: np.ndarray, *, path: Path, what: str = "colour") -> np.ndarray:
    """Convert colour of any common encoding to uint8 so every format yields the same rgb.

    Integers up to 255 are kept; integers up to 65535 are taken as 16-bit and divided by 257
    (rounded); floats with maximum ≤ 1 are scaled by 255, larger floats are taken as 0–255.

    Parameters
    ----------
    channels : ndarray of shape (N, 3)
        Red, green, blue in the file's dtype.
    path : Path
        The file, for messages.
    what : str
        Names the source of the values in messages.

    Returns
    -------
    ndarray of shape (N, 3), uint8

    Raises
    ------
    ScanFormatError
        On non-finite, negative or too large values.
    """
    arr = np.asarray(channels)
    if arr.dtype == np.uint8:
        return np.ascontiguousarray(arr)
    if arr.size == 0:
        return np.zeros(arr.shape, dtype=np.uint8)
    if arr.dtype.kind == "b":
        return arr.astype(np.uint8) * np.uint8(255)
    if arr.dtype.kind == "f":
        if not np.isfinite(arr).all():
            bad = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
            raise ScanFormatError(
                f"{path}: {what} of point {bad} is not finite: {arr[bad].tolist()}"
            )
        lo, hi = float(arr.min()), float(arr.max())
        if lo < 0:
            raise ScanFormatError(f"{path}: {what} has negative values (minimum {lo})")
        if hi <= 1.0:
            return np.rint(arr * 255.0).astype(np.uint8)
        return np.rint(np.clip(arr, 0.0, 255.0)).astype(np.uint8)
    if arr.dtype.kind not in "iu":
        raise ScanFormatError(f"{path}: {what} has unsupported dtype {arr.dtype}")
    lo, hi = int(arr.min()), int(arr.max())
    if lo < 0:
        raise ScanFormatError(f"{path}: {what} has negative values (minimum {lo})")
    if hi <= 255:
        return arr.astype(np.uint8)
    if hi <= 65535:
        return np.rint(arr / 257.0).astype(np.uint8)
    raise ScanFormatError(
        f"{path}: {what} values up to {hi} exceed the 16-bit range; expected 0-255 or 0-65535"
    )


def normalise_labels(
    raw: np.ndarray,
    *,
    path: Path,
    source: str,
    raw_field: str = "raw_label",
    unlabelled_values: tuple[int, ...] = (),
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Map a file's label values to S3DIS indices so downstream code can trust the label range.

    Values in ``0..12`` and ``-1`` are kept; ``unlabelled_values`` become ``-1`` silently; any
    other value becomes ``-1`` with a logged warning, and then the raw values are also returned
    as field ``raw_field`` so nothing is lost.

    Parameters
    ----------
    raw : ndarray of shape (N,)
        Label values as stored (any numeric dtype; floats must be whole numbers).
    path : Path
        The file, for messages.
    source : str
        The property / column name the labels came from, for messages.
    raw_field : str
        Name of the field keeping the raw values when some are out of range.
    unlabelled_values : tuple of int
        Values meaning "no label" in this format (e.g. 255 in LAS).

    Returns
    -------
    labels : ndarray of shape (N,), int32
    extra : dict
        ``{raw_field: raw}`` when some values were out of range, else empty.

    Raises
    ------
    ScanFormatError
        When the values are not whole numbers.
    """
    arr = np.asarray(raw)
    if arr.dtype.kind == "b":
        arr = arr.astype(np.int32)
    if arr.dtype.kind == "f":
        bad_mask = ~np.isfinite(arr) | (np.rint(arr) != arr)
        if bad_mask.any():
            bad = int(np.flatnonzero(bad_mask)[0])
            raise ScanFormatError(
                f"{path}: label {source!r} must hold whole numbers; point {bad} has {arr[bad]}"
            )
    elif arr.dtype.kind not in "iu":
        raise ScanFormatError(f"{path}: label {source!r} has unsupported dtype {arr.dtype}")
    values = arr.astype(np.int64)
    labels = values.copy()
    for v in unlabelled_values:
        labels[values == v] = UNLABELLED
    out = (labels < UNLABELLED) | (labels >= NUM_CLASSES)
    extra: dict[str, np.ndarray] = {}
    if out.any():
        odd = np.unique(values[out])
        logger.warning(
            "%s: %d points have %s values outside the S3DIS classes 0..%d (%s); they are read "
            "as unlabelled (-1) and the raw values are kept in field %r",
            path,
            int(out.sum()),
            source,
            NUM_CLASSES - 1,
            ", ".join(str(v) for v in odd[:10].tolist()) + (" ..." if odd.size > 10 else ""),
            raw_field,
        )
        labels[out] = UNLABELLED
        extra[raw_field] = np.asarray(raw)
    return labels.astype(np.int32), extra


def build_scan(
    path: Path,
    fmt: str,
    xyz: np.ndarray,
    rgb: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    fields: Mapping[str, np.ndarray] | None = None,
    *,
    locate: Callable[[int], str] | None = None,
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
        where = f"point {bad}" + (f" ({locate(bad)})" if locate is not None else "")
        raise ScanFormatError(
            f"{path}: {where} has non-finite coordinates {xyz[bad].tolist()} "
            f"({bad_rows.size} such points in all); coordinates must be finite numbers"
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


def safe_field_name(name: str, *, path: Path) -> str:
    """Turn a field name into one every header format accepts (letters, digits, ``_``).

    Other characters become ``_`` (and a leading digit gets a ``_`` prefix), with a warning.
    """
    safe = re.sub(r"[^A-Za-z0-9_]", "_", name) or "_"
    if safe[0].isdigit():
        safe = "_" + safe
    if safe != name:
        logger.warning("%s: field %r is written as %r", path, name, safe)
    return safe


def flatten_fields(fields: Mapping[str, np.ndarray], *, path: Path) -> dict[str, np.ndarray]:
    """Split 2-D fields into 1-D columns for formats that store only scalar attributes.

    A field ``f`` of shape (N, k) becomes ``f_0 .. f_{k-1}``; reading the file back yields those
    1-D fields (not the original 2-D one). Names are made header-safe by
    :func:`safe_field_name`.

    Parameters
    ----------
    fields : dict of str to ndarray of shape (N,) or (N, k)
    path : Path
        The target file, for messages.

    Returns
    -------
    dict of str to ndarray of shape (N,)

    Raises
    ------
    ScanFormatError
        When two columns end up with the same name.
    """
    out: dict[str, np.ndarray] = {}
    for name, values in fields.items():
        base = safe_field_name(name, path=path)
        arr = np.asarray(values)
        if arr.ndim == 1:
            cols = {base: arr}
        else:
            cols = {f"{base}_{i}": arr[:, i] for i in range(arr.shape[1])}
        for col, data in cols.items():
            if col in out or (col != name and col in fields):
                raise ScanFormatError(
                    f"{path}: two fields would both be written as {col!r} (a 2-D field {base!r} "
                    f"is written as {base}_0, {base}_1, ...); rename one"
                )
            out[col] = np.ascontiguousarray(data)
    return out


def narrow_dtype(
    arr: np.ndarray, *, name: str, path: Path, allow_64bit_int: bool = False
) -> np.ndarray:
    """Convert a field to a dtype a fixed-type format can store, refusing lossy conversions.

    bool becomes uint8, float16 becomes float32; int64/uint64 become int32/uint32 when the values
    fit and float64 when they are exactly representable there (|v| ≤ 2**53).

    Parameters
    ----------
    arr : ndarray of shape (N,)
    name : str
        Field name, for messages.
    path : Path
        Target file, for messages.
    allow_64bit_int : bool
        Keep int64/uint64 as they are (for formats that store them).

    Returns
    -------
    ndarray of shape (N,)

    Raises
    ------
    ScanFormatError
        For non-numeric dtypes or 64-bit integers that cannot be stored exactly.
    """
    kind, size = arr.dtype.kind, arr.dtype.itemsize
    if kind == "b":
        return arr.astype(np.uint8)
    if kind == "f":
        if size == 2:
            return arr.astype(np.float32)
        if size > 8:
            return arr.astype(np.float64)
        return arr.astype(arr.dtype.newbyteorder("="), copy=False)
    if kind in "iu":
        arr = arr.astype(arr.dtype.newbyteorder("="), copy=False)
        if size < 8 or allow_64bit_int:
            return arr
        if arr.size == 0:
            return arr.astype(np.int32 if kind == "i" else np.uint32)
        lo, hi = int(arr.min()), int(arr.max())
        small = np.iinfo(np.int32 if kind == "i" else np.uint32)
        if small.min <= lo and hi <= small.max:
            return arr.astype(np.int32 if kind == "i" else np.uint32)
        if max(abs(lo), abs(hi)) <= 2**53:
            logger.warning("%s: field %r (%s) is stored as float64", path, name, arr.dtype)
            return arr.astype(np.float64)
        raise ScanFormatError(
            f"{path}: field {name!r} has {arr.dtype} values beyond ±2**53 that this format cannot "
            f"store exactly"
        )
    raise ScanFormatError(
        f"{path}: field {name!r} has dtype {arr.dtype}; only numeric and bool fields can be written"
    )
