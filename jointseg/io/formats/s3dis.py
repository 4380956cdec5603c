"""S3DIS room folders: ``<room>/Annotations/<class>_<n>.txt``, one labelled file per object.

Each annotation file is an ``x y z r g b`` text list; its class comes from the file name
(``stairs`` is mapped to ``clutter``, as in the standard S3DIS preparation), and every object
gets a distinct number in the int32 field ``instance`` (0, 1, ... in file-name order). The
whole-room file ``<room>/<room>.txt`` (unlabelled) is read by the text reader when given
directly.
"""

from __future__ import annotations

import logging
import mmap
import re
from pathlib import Path

import numpy as np

from jointseg.classes import CLASS_INDEX, CLASS_NAMES
from jointseg.exceptions import ScanFormatError
from jointseg.io.build import build_scan
from jointseg.io.colour import to_rgb8
from jointseg.io.formats.text import read_text_table, sniff_text
from jointseg.io.limits import ScanInfo, check_max_points
from jointseg.io.tabular import count_lines
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

#: Class names that S3DIS uses beyond the 13 standard ones, and the class they count as.
CLASS_ALIASES: dict[str, str] = {"stairs": "clutter"}

_OBJECT_FILE = re.compile(r"^(?P<cls>[A-Za-z]+)_(?P<n>\d+)\.txt$")


def annotations_dir(path: Path) -> Path:
    """Return the ``Annotations`` folder of a room folder (or the folder itself if so named).

    Raises
    ------
    ScanFormatError
        When neither ``path/Annotations`` exists nor ``path`` is such a folder.
    """
    if path.name == "Annotations" and path.is_dir():
        return path
    ann = path / "Annotations"
    if ann.is_dir():
        return ann
    raise ScanFormatError(
        f"{path}: is a folder but not an S3DIS room (no Annotations/ subfolder with "
        f"<class>_<n>.txt files); give a scan file instead"
    )


def object_files(path: Path) -> list[tuple[Path, int]]:
    """List the room's annotation files with their class index, in a stable order.

    Parameters
    ----------
    path : Path
        Room folder (or its ``Annotations`` folder).

    Returns
    -------
    list of (Path, int)
        Each object file and its S3DIS class index.

    Raises
    ------
    ScanFormatError
        On a ``.txt`` file whose name is not ``<class>_<n>.txt`` or whose class is unknown, or
        when there are no object files.
    """
    ann = annotations_dir(path)
    out = []
    for file in sorted(ann.iterdir(), key=_natural_key):
        if file.suffix.lower() != ".txt" or not file.is_file():
            continue
        match = _OBJECT_FILE.match(file.name)
        if match is None:
            raise ScanFormatError(
                f"{file}: annotation file names must look like <class>_<n>.txt (e.g. chair_3.txt)"
            )
        cls = match["cls"].lower()
        cls = CLASS_ALIASES.get(cls, cls)
        if cls not in CLASS_INDEX:
            raise ScanFormatError(
                f"{file}: unknown S3DIS class {match['cls']!r}; known classes: "
                f"{', '.join(CLASS_NAMES)} (and {', '.join(CLASS_ALIASES)})"
            )
        out.append((file, CLASS_INDEX[cls]))
    if not out:
        raise ScanFormatError(f"{ann}: no <class>_<n>.txt annotation files found")
    return out


def _natural_key(path: Path) -> tuple[object, ...]:
    return tuple(int(p) if p.isdigit() else p for p in re.split(r"(\d+)", path.name))


def read_s3dis_room(path: Path, *, max_points: int, progress: ProgressFn | None = None) -> Scan:
    """Read a labelled S3DIS room from its annotation files.

    Parameters
    ----------
    path : Path
        Room folder (containing ``Annotations/``) or the ``Annotations`` folder.
    max_points : int
        Refuse rooms with more points in all.
    progress : ProgressFn, optional
        Receives ``("read", fraction)`` after each object file.

    Returns
    -------
    Scan
        With labels from the file names and field ``instance`` (int32).

    Raises
    ------
    ScanFormatError
        On a badly named file, an unknown class, a malformed annotation file (naming the file
        and line), non-finite coordinates or too many points.
    """
    files = object_files(path)
    xyz_parts, rgb_parts, label_parts, inst_parts = [], [], [], []
    total = 0
    where: list[tuple[int, Path, np.ndarray]] = []
    report(progress, "read", 0.0)
    for k, (file, cls) in enumerate(files):
        if file.stat().st_size == 0:
            logger.warning("%s: empty annotation file skipped", file)
            continue
        with open(file, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            values, lines, _ = read_text_table(buf, file, max_points=max_points)
        if values.shape[1] != 6:
            raise ScanFormatError(
                f"{file}: line {int(lines[0])} has {values.shape[1]} columns; S3DIS annotation "
                f"files hold 6 (x y z r g b)"
            )
        n = values.shape[0]
        where.append((total, file, lines))
        total += n
        check_max_points(total, max_points, path, what="at least ")
        xyz_parts.append(values[:, :3])
        rgb_parts.append(to_rgb8(values[:, 3:6], path=file))
        label_parts.append(np.full(n, cls, dtype=np.int32))
        inst_parts.append(np.full(n, k, dtype=np.int32))
        report(progress, "read", (k + 1) / len(files))
    if not xyz_parts:
        raise ScanFormatError(f"{path}: all annotation files are empty")

    def locate(i: int) -> str:
        start, file, lines = next(w for w in reversed(where) if w[0] <= i)
        return f"{file.name} line {int(lines[i - start])}"

    return build_scan(
        path,
        "s3dis",
        np.concatenate(xyz_parts),
        np.concatenate(rgb_parts),
        np.concatenate(label_parts),
        {"instance": np.concatenate(inst_parts)},
        locate=locate,
    )


def probe_s3dis_room(path: Path, *, max_points: int) -> ScanInfo:
    """Check the annotation file names and count their lines.

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
        On a badly named file, an unknown class or too many points.
    """
    n = 0
    for file, _ in object_files(path):
        if file.stat().st_size == 0:
            continue
        with open(file, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            offset = sniff_text(buf, file)[0]
            n += count_lines(buf, offset)
    check_max_points(n, max_points, path)
    return ScanInfo(
        path=str(path),
        format="s3dis",
        n_points=n,
        has_rgb=True,
        has_labels=True,
        fields=("instance",),
    )
