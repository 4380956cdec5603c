"""Plain-text point lists (S3DIS ``x y z r g b [label]``, XYZ, CSV), read fast with numpy.

Columns are separated by spaces, tabs or commas. Without a header the column count decides the
meaning: 3 = ``x y z``, 4 = ``x y z intensity``, 6 = ``x y z r g b``, 7 = ``x y z r g b label``.
A first line that is not numeric is a header (``//X,Y,Z,R,G,B`` or ``x y z label ...``); when it
names x, y and z its names decide the meaning instead (colour, label and other columns as fields).

Written files are S3DIS-compatible: ``x y z [r g b] [label]`` without a header, except that CSV
files always get one, and so does ``x y z label`` (which would otherwise read as intensity).
Extra fields are not written to text files (a warning says so); use PLY, LAS, PCD or NPZ to keep
them.
"""

from __future__ import annotations

import logging
import mmap
from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError
from jointseg.io.atomic import atomic_open
from jointseg.io.build import build_scan
from jointseg.io.colour import to_rgb8
from jointseg.io.columns import LABEL_NAMES, pick_colour_names, pick_name
from jointseg.io.labels import normalise_labels
from jointseg.io.limits import ScanInfo, check_max_points
from jointseg.io.tabular import count_lines, parse_table
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

#: Column meaning by column count when the file has no header naming them.
POSITIONAL_COLUMNS: dict[int, tuple[str, ...]] = {
    3: ("x", "y", "z"),
    4: ("x", "y", "z", "intensity"),
    6: ("x", "y", "z", "red", "green", "blue"),
    7: ("x", "y", "z", "red", "green", "blue", "label"),
}

_ROWS_PER_WRITE = 200_000


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _split(line: str) -> list[str]:
    return line.replace(",", " ").split()


def sniff_text(buf: bytes | mmap.mmap, path: Path) -> tuple[int, int, list[str] | None, bool]:
    """Find where the numbers start, the header names (if any) and whether commas separate values.

    Parameters
    ----------
    buf : bytes or mmap
        File content.
    path : Path
        The file, for messages.

    Returns
    -------
    offset : int
        Byte offset of the first data line.
    first_line : int
        Its 1-based line number.
    names : list of str or None
        Header names when the first non-blank line is not numeric.
    comma : bool
        Whether the data is comma-separated.

    Raises
    ------
    ScanFormatError
        When the file holds no data line or more than one non-numeric line at the top.
    """
    pos, line_no = (3 if buf[:3] == b"\xef\xbb\xbf" else 0), 1  # skip a UTF-8 BOM
    names: list[str] | None = None
    size = len(buf)
    while pos < size:
        nl = buf.find(b"\n", pos)
        end = size if nl < 0 else nl + 1
        raw = buf[pos:end]
        try:
            line = raw.decode("utf-8").strip()
        except UnicodeDecodeError as exc:
            raise ScanFormatError(
                f"{path}: line {line_no} is not text; is this really a {path.suffix} point list?"
            ) from exc
        if line:
            tokens = _split(line.lstrip("/#"))
            if all(_is_number(t) for t in tokens) and not line.startswith(("/", "#")):
                return pos, line_no, names, "," in line
            if names is not None:
                raise ScanFormatError(
                    f"{path}: line {line_no} is not numeric ({line[:60]!r}); only one header "
                    f"line is allowed before the x y z ... rows"
                )
            names = tokens
        pos, line_no = end, line_no + 1
    raise ScanFormatError(f"{path}: no data lines found (the file has only a header or blanks)")


def columns_to_parts(
    values: np.ndarray, names: list[str] | None, *, path: Path
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, dict[str, np.ndarray]]:
    """Split a numeric table into xyz, colour, labels and fields by header names or column count.

    Parameters
    ----------
    values : ndarray of shape (N, C)
        The table (any numeric dtype).
    names : list of str, optional
        Column names from a header; ignored unless it names x, y and z and has C entries.
    path : Path
        The file, for messages.

    Returns
    -------
    xyz : ndarray of shape (N, 3)
    rgb : ndarray of shape (N, 3), uint8, or None
    labels : ndarray of shape (N,), int32, or None
    fields : dict of str to ndarray of shape (N,)

    Raises
    ------
    ScanFormatError
        On a column count with no known meaning, or duplicate header names.
    """
    ncols = values.shape[1]
    named = (
        names is not None
        and len(names) == ncols
        and all(pick_name(names, (axis,)) is not None for axis in "xyz")
    )
    if names is not None and not named:
        logger.info("%s: header %s does not name x, y, z per column; ignoring it", path, names)
    if named:
        assert names is not None
        if len({n.lower() for n in names}) != len(names):
            raise ScanFormatError(f"{path}: the header repeats a column name: {names}")
        cols = list(names)
    elif ncols in POSITIONAL_COLUMNS:
        cols = list(POSITIONAL_COLUMNS[ncols])
    else:
        raise ScanFormatError(
            f"{path}: rows have {ncols} columns; expected 3 (x y z), 4 (x y z intensity), "
            f"6 (x y z r g b) or 7 (x y z r g b label), or a header line naming the columns"
        )
    index = {name: i for i, name in enumerate(cols)}
    used: set[str] = set()
    axes = [pick_name(cols, (a,)) for a in "xyz"]
    used.update(a for a in axes if a is not None)
    xyz = values[:, [index[a] for a in axes if a is not None]]
    rgb = None
    colour = pick_colour_names(cols)
    if colour is not None:
        used.update(colour)
        rgb = to_rgb8(values[:, [index[c] for c in colour]], path=path)
    labels = None
    fields: dict[str, np.ndarray] = {}
    label_name = pick_name(cols, LABEL_NAMES)
    if label_name is not None:
        used.add(label_name)
        labels, fields = normalise_labels(
            values[:, index[label_name]], path=path, source=label_name
        )
    for name in cols:
        if name not in used:
            fields[name] = np.ascontiguousarray(values[:, index[name]])
    return xyz, rgb, labels, fields


def read_text(path: Path, *, fmt: str, max_points: int, progress: ProgressFn | None = None) -> Scan:
    """Read a TXT/XYZ/CSV point list.

    Parameters
    ----------
    path : Path
        The file.
    fmt : str
        Format name to record (``"txt"``, ``"xyz"`` or ``"csv"``).
    max_points : int
        Refuse files with more points.
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    Scan

    Raises
    ------
    ScanFormatError
        On a wrong column count or non-numeric token (naming the line), non-finite coordinates
        (naming the line) or too many points.
    """
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
        values, lines, names = read_text_table(buf, path, max_points=max_points, progress=progress)
    xyz, rgb, labels, fields = columns_to_parts(values, names, path=path)
    return build_scan(path, fmt, xyz, rgb, labels, fields, locate=lambda i: f"line {int(lines[i])}")


def read_text_table(
    buf: bytes | mmap.mmap,
    path: Path,
    *,
    max_points: int,
    ncols: int | None = None,
    progress: ProgressFn | None = None,
) -> tuple[np.ndarray, np.ndarray, list[str] | None]:
    """Parse a text point list into its table, line numbers and header names.

    Parameters
    ----------
    buf : bytes or mmap
        File content.
    path : Path
        The file, for messages.
    max_points : int
        Refuse files with more data lines.
    ncols : int, optional
        Required column count.
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    values : ndarray of shape (N, C), float64
    lines : ndarray of shape (N,), int64
        1-based line number of every row.
    names : list of str or None
        Header names.

    Raises
    ------
    ScanFormatError
        As :func:`read_text`.
    """
    offset, first_line, names, comma = sniff_text(buf, path)
    if (len(buf) - offset) // 6 > max_points:  # "0 0 0\n" is the shortest possible point line
        n_lines = count_lines(buf, offset)
        check_max_points(n_lines, max_points, path, what="about ")

    def too_many(rows: int) -> ScanFormatError:
        n_lines = count_lines(buf, offset)
        return ScanFormatError(
            f"{path}: the scan has about {max(rows, n_lines):,} points, more than "
            f"max_points={max_points:,}; pass a larger max_points to read it, or subsample it first"
        )

    values, lines = parse_table(
        buf,
        path=path,
        start=offset,
        first_line=first_line,
        ncols=ncols,
        comma=comma,
        limit=max_points,
        on_limit=too_many,
        progress=progress,
    )
    return values, lines, names


def probe_text(path: Path, *, fmt: str, max_points: int) -> ScanInfo:
    """Count the data lines and read the header of a text point list (no number parsing).

    Parameters
    ----------
    path : Path
    fmt : str
    max_points : int

    Returns
    -------
    ScanInfo

    Raises
    ------
    ScanFormatError
        When the file has no data lines, a column count with no known meaning, or too many lines.
    """
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
        offset, _, names, comma = sniff_text(buf, path)
        nl = buf.find(b"\n", offset)
        first = buf[offset : len(buf) if nl < 0 else nl].decode("utf-8", "replace")
        n_points = count_lines(buf, offset)
    ncols = len(_split(first))
    check_max_points(n_points, max_points, path)
    # Reuse the column logic on one fake row to learn which parts are present.
    xyz, rgb, labels, fields = columns_to_parts(np.zeros((1, ncols)), names, path=path)
    return ScanInfo(
        path=str(path),
        format=fmt,
        n_points=n_points,
        has_rgb=rgb is not None,
        has_labels=labels is not None,
        fields=tuple(fields),
    )


def write_text(scan: Scan, path: Path, *, comma: bool, progress: ProgressFn | None = None) -> None:
    """Write ``x y z [r g b] [label]`` rows, coordinates with full float64 precision.

    Parameters
    ----------
    scan : Scan
    path : Path
        Target file (written atomically).
    comma : bool
        Separate values by commas (CSV) instead of spaces; CSV files get a header line.
    progress : ProgressFn, optional
        Receives ``("write", fraction)``.
    """
    if scan.fields:
        logger.warning(
            "%s: text files keep only x y z r g b label; fields %s are not written",
            path,
            sorted(scan.fields),
        )
    names = ["x", "y", "z"]
    if scan.rgb is not None:
        names += ["red", "green", "blue"]
    if scan.labels is not None:
        names.append("label")
    sep = "," if comma else " "
    header = comma or len(names) not in (3, 6, 7) or tuple(names) != POSITIONAL_COLUMNS[len(names)]
    n = len(scan)
    with atomic_open(path) as fh:
        if header:
            fh.write(("//" + sep.join(names) + "\n").encode())
        for lo in range(0, n, _ROWS_PER_WRITE):
            hi = min(n, lo + _ROWS_PER_WRITE)
            cols: list[list[object]] = [scan.xyz[lo:hi, i].tolist() for i in range(3)]
            if scan.rgb is not None:
                cols += [scan.rgb[lo:hi, i].tolist() for i in range(3)]
            if scan.labels is not None:
                cols.append(scan.labels[lo:hi].tolist())
            rows = [sep.join(map(repr, row)) for row in zip(*cols, strict=True)]
            fh.write(("\n".join(rows) + "\n").encode())
            report(progress, "write", hi / max(1, n))
