"""Fields as scalar columns of storable dtypes, for formats with fixed-type scalar attributes.

Writers plan the columns and dtypes here once, so renamed fields and narrowed dtypes are the
same (and warned about once) whether a scan is written whole or chunk by chunk.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError

logger = logging.getLogger(__name__)


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
    """Plan how ``fields`` split into 1-D columns, without copying values.

    A field ``f`` of shape (N, k) becomes ``f_0 .. f_{k-1}``; reading the file back yields those
    1-D fields (not the original 2-D one). Names are made header-safe by
    :func:`safe_field_name`. A writer that goes chunk by chunk makes the plan once (warnings
    about renamed fields are logged once) and takes each chunk's columns with
    :meth:`FieldColumn.take`.

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
