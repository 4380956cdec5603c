"""What is checked before a scan's body is read, so bad or oversized inputs cost nothing.

Holds the point limit every reader takes, the plain checks on the input path, the library
errors that mean a bad input (:data:`INPUT_ERRORS`), and :class:`ScanInfo`, what a probe
reports from those cheap looks.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

from pydantic import BaseModel, ConfigDict

from jointseg.exceptions import ScanFormatError

#: Default upper bound on the number of points a reader accepts.
DEFAULT_MAX_POINTS: int = 50_000_000
#: Default ceiling on how many times more bytes a compressed scan (LAZ, compressed NPZ,
#: binary_compressed PCD, E57) may declare than the file stores. The most LAZ gets is about
#: 3,400 (a million identical points in 10 KB) and deflate about 1,030, so no honest file comes
#: near it; a 6 KB LAZ whose header claims 40 M points (200,000 times) is refused before
#: anything is allocated. The job service sets a lower one (``JOINTSEG_MAX_INFLATION``).
DEFAULT_MAX_INFLATION: float = 10_000.0
#: Errors third-party readers raise on bad input that a format module did not already wrap.
INPUT_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile)


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


def check_inflation(
    declared: int, stored: int, max_inflation: float, path: Path, *, what: str
) -> None:
    """Refuse a file whose header declares far more data than its size can hold, before any
    of it is allocated or decompressed (a lying header, or a decompression bomb).

    Parameters
    ----------
    declared : int
        Bytes the header says the points take once decompressed.
    stored : int
        Bytes the file holds for them.
    max_inflation : float
        Largest accepted ``declared / stored``.
    path : Path
        The file, for the message.
    what : str
        What declares it, e.g. ``"the LAZ header's 40,000,000 points"``.

    Raises
    ------
    ScanFormatError
        When ``declared > max_inflation * stored``.
    """
    if declared > max_inflation * max(stored, 1):
        raise ScanFormatError(
            f"{path}: {what} take {declared:,} bytes, {declared / max(stored, 1):,.0f} times "
            f"the {stored:,} bytes stored; at most {max_inflation:,g} times is accepted "
            f"(max_inflation): the header's count is wrong, or the file is a compression bomb"
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
