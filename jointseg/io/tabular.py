"""Fast parsing of whitespace- or comma-separated numeric tables (TXT/XYZ/CSV, ASCII PLY/PCD).

The buffer is cut into chunks at line boundaries; per chunk, the number of tokens on every line
is counted with numpy (so a wrong column count is reported with its line number) and the numbers
are parsed in C by :func:`numpy.fromstring`. Python-level per-line work happens only to locate an
unparsable token after the fast path has failed.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from jointseg.exceptions import ScanFormatError
from jointseg.progress import ProgressFn, report

logger = logging.getLogger(__name__)

#: Bytes per parsing chunk (cut at the next newline).
CHUNK_BYTES: int = 4 << 20


class Buffer(Protocol):
    """What the parser needs of its input: ``bytes`` or :class:`mmap.mmap`."""

    def find(self, sub: bytes, start: int = ..., end: int = ...) -> int: ...

    def __getitem__(self, key: slice) -> bytes: ...

    def __len__(self) -> int: ...


def _separators(arr: np.ndarray, comma: bool) -> np.ndarray:
    sep = (arr == 32) | (arr == 9) | (arr == 10) | (arr == 13)
    if comma:
        sep |= arr == 44
    return sep


def line_token_counts(chunk: bytes, *, comma: bool) -> np.ndarray:
    """Count the tokens on every line of ``chunk`` without a Python loop.

    Parameters
    ----------
    chunk : bytes
        Text; a final line without a newline counts as a line.
    comma : bool
        Whether commas separate tokens (in addition to spaces and tabs).

    Returns
    -------
    ndarray of shape (L,), int64
        Tokens per line; blank lines count 0.
    """
    arr = np.frombuffer(chunk, dtype=np.uint8)
    if arr.size == 0:
        return np.zeros(0, dtype=np.int64)
    sep = _separators(arr, comma)
    starts = ~sep
    starts[1:] &= sep[:-1]
    newlines = np.flatnonzero(arr == 10)
    n_lines = newlines.size + (0 if arr[-1] == 10 else 1)
    line_of_token = np.searchsorted(newlines, np.flatnonzero(starts))
    return np.bincount(line_of_token, minlength=n_lines).astype(np.int64)


def count_lines(buf: Buffer, start: int = 0, stop: int | None = None) -> int:
    """Number of lines in ``buf[start:stop]`` (a last line without newline counts)."""
    stop = len(buf) if stop is None else stop
    n = 0
    last = b"\n"
    pos = start
    while pos < stop:
        end = min(stop, pos + CHUNK_BYTES * 4)
        piece = buf[pos:end]
        n += piece.count(b"\n")
        last = piece[-1:]
        pos = end
    return n + (0 if last == b"\n" else 1)


def _parses(text: str, n_tokens: int) -> bool:
    """Whether numpy's parser (the one the fast path uses) reads exactly ``n_tokens`` numbers."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            return np.fromstring(text, dtype=np.float64, sep=" ").size == n_tokens
    except ValueError:
        return False


def _locate_bad_token(text: str, first_line: int) -> tuple[int, str]:
    """Find the first token that is not a number (slow path, used only after a parse failure)."""
    for offset, line in enumerate(text.split("\n")):
        tokens = line.split()
        if tokens and not _parses(line, len(tokens)):
            bad = next((t for t in tokens if not _parses(t, 1)), line.strip())
            return first_line + offset, bad
    return first_line, "?"


def _chunk_end(buf: Buffer, pos: int, stop: int) -> int:
    """End of the chunk starting at ``pos``: about CHUNK_BYTES on, cut after the next newline."""
    end = min(stop, pos + CHUNK_BYTES)
    if end < stop:
        nl = buf.find(b"\n", end, stop)
        end = stop if nl < 0 else nl + 1
    return end


def _check_limit(
    path: Path, rows: int, limit: int | None, on_limit: Callable[[int], ScanFormatError] | None
) -> None:
    """Raise the caller's error (or a generic one) once more than ``limit`` rows were read."""
    if limit is not None and rows > limit:
        if on_limit is None:
            raise ScanFormatError(f"{path}: more than {limit} rows")
        raise on_limit(rows)


def _stacked(
    values: list[np.ndarray], lines: list[np.ndarray], ncols: int | None
) -> tuple[np.ndarray, np.ndarray]:
    """Join the chunks' rows and line numbers; an empty table keeps its known width."""
    if not values:
        width = ncols or 0
        return np.zeros((0, width)), np.zeros(0, dtype=np.int64)
    return np.concatenate(values), np.concatenate(lines)


def _parse_chunk(
    chunk: bytes,
    counts: np.ndarray,
    data_idx: np.ndarray,
    *,
    ncols: int,
    comma: bool,
    path: Path,
    line_no: int,
) -> np.ndarray:
    """Check the column count of every data line of one chunk and parse it into (rows, ncols).

    Kept out of :func:`parse_table` so the chunk loop stays readable; ``line_no`` is the 1-based
    number of the chunk's first line, for messages.
    """
    wrong = data_idx[counts[data_idx] != ncols]
    if wrong.size:
        bad = int(wrong[0])
        raise ScanFormatError(
            f"{path}: line {line_no + bad} has {int(counts[bad])} columns, expected "
            f"{ncols} (as on the lines before)"
        )
    text = chunk.decode("latin-1")
    if comma:
        text = text.replace(",", " ")
    try:
        with warnings.catch_warnings():
            # numpy < 2.3 warns and returns a short array; newer versions raise.
            warnings.simplefilter("ignore", DeprecationWarning)
            parsed = np.fromstring(text, dtype=np.float64, sep=" ")
    except ValueError:
        parsed = np.zeros(0)
    if parsed.size != data_idx.size * ncols:
        bad_line, token = _locate_bad_token(text, line_no)
        raise ScanFormatError(f"{path}: line {bad_line}: cannot read {token[:40]!r} as a number")
    return parsed.reshape(-1, ncols)


def parse_table(
    buf: Buffer,
    *,
    path: Path,
    start: int = 0,
    stop: int | None = None,
    first_line: int = 1,
    ncols: int | None = None,
    comma: bool = False,
    limit: int | None = None,
    on_limit: Callable[[int], ScanFormatError] | None = None,
    progress: ProgressFn | None = None,
    stage: str = "read",
) -> tuple[np.ndarray, np.ndarray]:
    """Parse the numeric table in ``buf[start:stop]`` into a float64 array, checking every line.

    Blank lines are skipped; every other line must hold the same number of tokens.

    Parameters
    ----------
    buf : bytes or mmap
        The file content.
    path : Path
        The file, for messages.
    start, stop : int
        Byte range to parse; ``start`` must be at the beginning of a line.
    first_line : int
        1-based line number of the line at ``start``.
    ncols : int, optional
        Required tokens per line; when None, the first non-blank line sets it.
    comma : bool
        Whether commas separate values.
    limit : int, optional
        Maximum number of rows; exceeding it raises ``on_limit(rows_so_far)``.
    on_limit : callable, optional
        Builds the error raised when ``limit`` is exceeded.
    progress : ProgressFn, optional
        Called with the fraction of bytes parsed.
    stage : str
        Stage name passed to ``progress``.

    Returns
    -------
    values : ndarray of shape (N, ncols), float64
    lines : ndarray of shape (N,), int64
        1-based line number of every row, for messages about individual points.

    Raises
    ------
    ScanFormatError
        On a line with the wrong number of columns or a token that is not a number (naming the
        line), or when ``limit`` is exceeded.
    """
    stop = len(buf) if stop is None else stop
    values: list[np.ndarray] = []
    lines: list[np.ndarray] = []
    rows = 0
    pos = start
    line_no = first_line
    total = max(1, stop - start)
    while pos < stop:
        end = _chunk_end(buf, pos, stop)
        chunk = buf[pos:end]
        counts = line_token_counts(chunk, comma=comma)
        data_idx = np.flatnonzero(counts)
        if data_idx.size:
            if ncols is None:
                ncols = int(counts[data_idx[0]])
            parsed = _parse_chunk(
                chunk, counts, data_idx, ncols=ncols, comma=comma, path=path, line_no=line_no
            )
            values.append(parsed)
            lines.append(data_idx + line_no)
            rows += data_idx.size
            _check_limit(path, rows, limit, on_limit)
        line_no += counts.size
        pos = end
        report(progress, stage, (pos - start) / total)
    return _stacked(values, lines, ncols)
