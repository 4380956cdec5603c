"""Checks and conversions shared by every scan reader and writer.

Each format module turns its file into plain arrays and hands them to :func:`build_scan`, so the
rules for colour scaling, label normalisation, coordinate checks and error wording live here once.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
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


#: A colour value range ``(minimum, maximum)``: what decides how :func:`to_rgb8` reads colour.
ColourRange = tuple[float, float]


def colour_range(
    channels: np.ndarray, *, path: Path, what: str = "colour", start: int = 0
) -> ColourRange | None:
    """The smallest and largest colour value, which decide the encoding :func:`to_rgb8` assumes.

    Kept apart from the conversion so a reader that goes through a file in chunks can take that
    decision once for the whole file: 16-bit colour whose first chunk happens to be dark (all
    ≤ 255) must still be divided by 257. Ranges of consecutive chunks combine with
    :func:`merge_colour_ranges`.

    Parameters
    ----------
    channels : ndarray of shape (N, 3)
        Red, green, blue in the file's dtype.
    path : Path
        The file, for messages.
    what : str
        Names the source of the values in messages.
    start : int
        Index of the first row in the file, so messages name the point in the whole file.

    Returns
    -------
    tuple of (float, float) or None
        None where the conversion needs no range: uint8 or bool colour, or no values.

    Raises
    ------
    ScanFormatError
        On non-finite values or a dtype that is not numeric.
    """
    arr = np.asarray(channels)
    if arr.dtype == np.uint8 or arr.dtype.kind == "b" or arr.size == 0:
        return None
    if arr.dtype.kind == "f":
        if not np.isfinite(arr).all():
            bad = int(np.flatnonzero(~np.isfinite(arr).all(axis=1))[0])
            raise ScanFormatError(
                f"{path}: {what} of point {start + bad} is not finite: {arr[bad].tolist()}"
            )
        return float(arr.min()), float(arr.max())
    if arr.dtype.kind not in "iu":
        raise ScanFormatError(f"{path}: {what} has unsupported dtype {arr.dtype}")
    return int(arr.min()), int(arr.max())


def merge_colour_ranges(a: ColourRange | None, b: ColourRange | None) -> ColourRange | None:
    """The range covering two chunks' ranges (None stands for "no range needed")."""
    if a is None or b is None:
        return a if b is None else b
    return min(a[0], b[0]), max(a[1], b[1])


def check_colour_range(kind: str, value_range: ColourRange, *, path: Path, what: str) -> None:
    """Refuse colour values no encoding explains (negative, or integers beyond 16 bits).

    Parameters
    ----------
    kind : str
        The dtype kind of the colour (``"f"``, ``"i"`` or ``"u"``).
    value_range : tuple of (float, float)
        The whole file's range, from :func:`colour_range`.
    path : Path
        The file, for messages.
    what : str
        Names the source of the values in messages.

    Raises
    ------
    ScanFormatError
        On negative values, or integers above 65535.
    """
    lo, hi = value_range
    if lo < 0:
        raise ScanFormatError(f"{path}: {what} has negative values (minimum {lo})")
    if kind != "f" and hi > 65535:
        raise ScanFormatError(
            f"{path}: {what} values up to {hi} exceed the 16-bit range; expected 0-255 or 0-65535"
        )


def to_rgb8(
    channels: np.ndarray,
    *,
    path: Path,
    what: str = "colour",
    value_range: ColourRange | None = None,
) -> np.ndarray:
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
    value_range : tuple of (float, float), optional
        The whole file's :func:`colour_range` when ``channels`` is one chunk of it, so every
        chunk is read with the same encoding; by default the range of ``channels``.

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
    if value_range is None:
        value_range = colour_range(arr, path=path, what=what)
        assert value_range is not None  # only uint8, bool and empty colour have none
    elif arr.dtype.kind not in "iuf":
        raise ScanFormatError(f"{path}: {what} has unsupported dtype {arr.dtype}")
    check_colour_range(arr.dtype.kind, value_range, path=path, what=what)
    hi = value_range[1]
    if arr.dtype.kind == "f":
        if hi <= 1.0:
            return np.rint(arr * 255.0).astype(np.uint8)
        return np.rint(np.clip(arr, 0.0, 255.0)).astype(np.uint8)
    if hi <= 255:
        return arr.astype(np.uint8)
    return np.rint(arr / 257.0).astype(np.uint8)


#: How many of the smallest out-of-range label values a :class:`LabelSummary` keeps (messages
#: list ten, and "..." when there are more).
_ODD_KEPT = 11


@dataclass(frozen=True)
class LabelSummary:
    """What a pass over a file's label values found that changes how every label is read.

    When some values are no S3DIS class, the raw values are kept as an extra field for every
    point of the file, so a reader that goes chunk by chunk needs this for the whole file before
    it hands out the first chunk (see :func:`label_summary`).

    Attributes
    ----------
    outside : int
        Points whose value is neither a class (0..12), -1, nor a value meaning "unlabelled".
    odd : tuple of int
        The smallest such values, sorted (at most 11).
    """

    outside: int = 0
    odd: tuple[int, ...] = ()

    def merge(self, other: LabelSummary) -> LabelSummary:
        """The summary of two consecutive chunks together."""
        odd = tuple(sorted(set(self.odd) | set(other.odd))[:_ODD_KEPT])
        return LabelSummary(self.outside + other.outside, odd)


def _label_values(raw: np.ndarray, *, path: Path, source: str, start: int) -> np.ndarray:
    """Label values as int64, refusing values that are not whole numbers."""
    arr = np.asarray(raw)
    if arr.dtype.kind == "b":
        arr = arr.astype(np.int32)
    if arr.dtype.kind == "f":
        bad_mask = ~np.isfinite(arr) | (np.rint(arr) != arr)
        if bad_mask.any():
            bad = int(np.flatnonzero(bad_mask)[0])
            raise ScanFormatError(
                f"{path}: label {source!r} must hold whole numbers; point {start + bad} has "
                f"{arr[bad]}"
            )
    elif arr.dtype.kind not in "iu":
        raise ScanFormatError(f"{path}: label {source!r} has unsupported dtype {arr.dtype}")
    return arr.astype(np.int64)


def _map_labels(
    values: np.ndarray, unlabelled_values: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Labels with the "unlabelled" values as -1, and the mask of values that are no class."""
    labels = values.copy()
    for v in unlabelled_values:
        labels[values == v] = UNLABELLED
    return labels, (labels < UNLABELLED) | (labels >= NUM_CLASSES)


def _summarise(values: np.ndarray, out: np.ndarray) -> LabelSummary:
    odd = np.unique(values[out])
    return LabelSummary(int(out.sum()), tuple(odd[:_ODD_KEPT].tolist()))


def label_summary(
    raw: np.ndarray,
    *,
    path: Path,
    source: str,
    unlabelled_values: tuple[int, ...] = (),
    start: int = 0,
) -> LabelSummary:
    """Check label values and count those that are no S3DIS class (see :class:`LabelSummary`).

    Parameters
    ----------
    raw : ndarray of shape (N,)
        Label values as stored (one chunk of a file, or all of it).
    path : Path
        The file, for messages.
    source : str
        The property / column name the labels come from, for messages.
    unlabelled_values : tuple of int
        Values meaning "no label" in this format (e.g. 255 in LAS).
    start : int
        Index of the first value in the file, so messages name the point in the whole file.

    Returns
    -------
    LabelSummary

    Raises
    ------
    ScanFormatError
        When the values are not whole numbers.
    """
    arr = np.asarray(raw)
    if arr.dtype.kind in "iu" and arr.size:
        if arr.min() >= UNLABELLED and arr.max() < NUM_CLASSES:
            return LabelSummary()  # the usual case, without int64 copies
        if arr.dtype == np.uint8:  # LAS classification: a histogram is cheaper than masks
            counts = np.bincount(arr.ravel(), minlength=256)
            counts[:NUM_CLASSES] = 0
            counts[[v for v in unlabelled_values if 0 <= v < 256]] = 0
            odd = np.flatnonzero(counts)
            return LabelSummary(int(counts.sum()), tuple(odd[:_ODD_KEPT].tolist()))
    values = _label_values(arr, path=path, source=source, start=start)
    return _summarise(values, _map_labels(values, unlabelled_values)[1])


def log_outside_labels(summary: LabelSummary, *, path: Path, source: str, raw_field: str) -> None:
    """Warn (once per file) that some label values are no class and are kept as ``raw_field``."""
    if not summary.outside:
        return
    logger.warning(
        "%s: %d points have %s values outside the S3DIS classes 0..%d (%s); they are read "
        "as unlabelled (-1) and the raw values are kept in field %r",
        path,
        summary.outside,
        source,
        NUM_CLASSES - 1,
        ", ".join(str(v) for v in summary.odd[:10]) + (" ..." if len(summary.odd) > 10 else ""),
        raw_field,
    )


def normalise_labels(
    raw: np.ndarray,
    *,
    path: Path,
    source: str,
    raw_field: str = "raw_label",
    unlabelled_values: tuple[int, ...] = (),
    summary: LabelSummary | None = None,
    start: int = 0,
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
    summary : LabelSummary, optional
        The whole file's :func:`label_summary` when ``raw`` is one chunk of it: then it decides
        whether ``raw_field`` is returned, and the caller has already warned
        (:func:`log_outside_labels`). By default ``raw`` is the whole file.
    start : int
        Index of the first value in the file, for messages.

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
    values = _label_values(raw, path=path, source=source, start=start)
    labels, out = _map_labels(values, unlabelled_values)
    if summary is None:
        summary = _summarise(values, out)
        log_outside_labels(summary, path=path, source=source, raw_field=raw_field)
    if out.any():
        labels[out] = UNLABELLED
    extra: dict[str, np.ndarray] = {}
    if summary.outside:
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


@dataclass(frozen=True)
class FieldColumn:
    """One scalar column a field becomes in formats that store only scalar attributes.

    Attributes
    ----------
    name : str
        The header-safe column name (see :func:`safe_field_name`).
    field : str
        The :attr:`Scan.fields` key it comes from.
    index : int or None
        The column of a 2-D field, None for a 1-D field.
    """

    name: str
    field: str
    index: int | None = None

    def take(self, fields: Mapping[str, np.ndarray]) -> np.ndarray:
        """This column's values from ``fields`` (contiguous)."""
        arr = np.asarray(fields[self.field])
        return np.ascontiguousarray(arr if self.index is None else arr[:, self.index])


def field_columns(fields: Mapping[str, np.ndarray], *, path: Path) -> list[FieldColumn]:
    """Plan how :func:`flatten_fields` splits ``fields`` into columns, without copying values.

    A writer that goes chunk by chunk makes the plan once (warnings about renamed fields are
    logged once) and takes each chunk's columns with :meth:`FieldColumn.take`.

    Parameters
    ----------
    fields : dict of str to ndarray of shape (N,) or (N, k)
    path : Path
        The target file, for messages.

    Returns
    -------
    list of FieldColumn

    Raises
    ------
    ScanFormatError
        When two columns end up with the same name.
    """
    out: dict[str, FieldColumn] = {}
    for name, values in fields.items():
        base = safe_field_name(name, path=path)
        shape = np.shape(values)
        if len(shape) == 1:
            cols = [FieldColumn(base, name)]
        else:
            cols = [FieldColumn(f"{base}_{i}", name, i) for i in range(shape[1])]
        for col in cols:
            if col.name in out or (col.name != name and col.name in fields):
                raise ScanFormatError(
                    f"{path}: two fields would both be written as {col.name!r} (a 2-D field "
                    f"{base!r} is written as {base}_0, {base}_1, ...); rename one"
                )
            out[col.name] = col
    return list(out.values())


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
    return {col.name: col.take(fields) for col in field_columns(fields, path=path)}


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


def narrow_like(arr: np.ndarray, dtype: np.dtype, *, name: str, path: Path) -> np.ndarray:
    """Convert one chunk of a field to the dtype :func:`narrow_dtype` chose from a sample.

    A writer that goes chunk by chunk fixes each column's dtype in the header before it sees
    most values; :func:`narrow_dtype` decides 64-bit integers by their values, so a later chunk
    may hold values the chosen dtype cannot store, which is refused rather than wrapped.

    Parameters
    ----------
    arr : ndarray of shape (N,)
        The chunk's values, of the same dtype as the sample's.
    dtype : numpy.dtype
        What :func:`narrow_dtype` returned for the sample.
    name : str
        Field name, for messages.
    path : Path
        Target file, for messages.

    Returns
    -------
    ndarray of shape (N,) and dtype ``dtype``

    Raises
    ------
    ScanFormatError
        When a value does not fit ``dtype`` exactly.
    """
    wide = dtype.kind in "iu" and dtype.itemsize == 8
    if arr.dtype.kind not in "iu" or arr.dtype.itemsize < 8 or wide:
        # every other conversion narrow_dtype makes depends on the dtype alone
        out = narrow_dtype(arr, name=name, path=path, allow_64bit_int=wide)
        return out.astype(dtype, copy=False)
    if arr.size:
        lo, hi = int(arr.min()), int(arr.max())
        if dtype.kind == "f":
            fits = max(abs(lo), abs(hi)) <= 2**53
        else:
            info = np.iinfo(dtype)
            fits = int(info.min) <= lo and hi <= int(info.max)
        if not fits:
            raise ScanFormatError(
                f"{path}: field {name!r} ({arr.dtype}) has values {lo}..{hi} that the column's "
                f"type {dtype}, chosen from the first chunk written, cannot hold exactly; convert "
                f"the field to float64 (or a type that holds every value) before writing"
            )
    return arr.astype(dtype)
