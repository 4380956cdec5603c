"""Label values as S3DIS class indices, so downstream code can trust the label range.

Values that are no class are read as unlabelled and the raw values kept as a field; a reader
that goes chunk by chunk needs a :class:`LabelSummary` of the whole file to decide that.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jointseg.classes import NUM_CLASSES, UNLABELLED
from jointseg.exceptions import ScanFormatError

logger = logging.getLogger(__name__)

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
