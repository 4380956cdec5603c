"""Colour of any common encoding (8/16-bit integers, 0-1 or 0-255 floats) as uint8 rgb.

The encoding is decided from a value range, kept apart from the conversion so a reader that
goes chunk by chunk decides it once for the whole file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError

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
