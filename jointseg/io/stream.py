"""Reading and writing scans chunk by chunk, so scans of any size fit in bounded memory (issue 16).

:func:`jointseg.io.read_scan` and :func:`jointseg.io.write_scan` hold a whole scan in memory; a
20-200 M point file needs several times its own size that way. Here a file is read as
consecutive chunks (each a :class:`~jointseg.scan.Scan`) and written from them:

- LAS/LAZ through laspy's chunked reader and writer (LAZ with lazrs), binary PLY through
  memory maps of one chunk of vertices at a time. Memory then grows with the chunk size, not
  with the file.
- Every other format (ASCII PLY, meshes (PLY with faces, GLB/glTF, OBJ), PCD, E57,
  TXT/XYZ/CSV, NPY/NPZ, S3DIS folders) falls back to reading the whole scan once and handing
  out slices of it, and to collecting the chunks and writing them at the end;
  :attr:`ScanChunks.streams` says which one a file gets.

Chunks read this way concatenate to exactly what ``read_scan`` returns, and a file written this
way is the one ``write_scan`` would write from the concatenated chunks.

Where it lives: :func:`open_chunks` and :func:`open_writer` dispatch through the
:class:`~jointseg.io.formats.Format` table, whose records name a format's streaming openers
(:mod:`jointseg.io.formats.las.stream`, :mod:`jointseg.io.formats.ply.stream`);
:mod:`jointseg.io.chunks` holds the types they return and the protocols they follow; this module
holds the fallback for formats without an opener.

Examples
--------
Copying a scan (``lo`` and ``hi``, the scan's xyz minimum and maximum, from a first loop over
the chunks):

>>> from jointseg.io.stream import open_chunks, open_writer       # doctest: +SKIP
>>> with open_chunks("big.laz") as source:                       # doctest: +SKIP
...     first = next(source.chunks(1))
...     with open_writer("out.ply", count=source.count, like=first, bounds=(lo, hi)) as out:
...         for chunk in source.chunks(2_000_000):
...             out.write(chunk)
"""

from __future__ import annotations

import logging
import os
from collections.abc import Generator
from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError, library_reason
from jointseg.io import read_scan, write_scan
from jointseg.io.chunks import DEFAULT_CHUNK_POINTS, ScanChunks, ScanWriter
from jointseg.io.dispatch import prepare_input, prepare_output
from jointseg.io.formats import get_format
from jointseg.io.limits import DEFAULT_MAX_INFLATION, DEFAULT_MAX_POINTS, INPUT_ERRORS
from jointseg.scan import Scan

__all__ = ["DEFAULT_CHUNK_POINTS", "ScanChunks", "ScanWriter", "open_chunks", "open_writer"]

logger = logging.getLogger(__name__)


class _WholeChunks(ScanChunks):
    """The fallback: the whole scan read once at open time, chunks are slices of it."""

    def __init__(self, scan: Scan, path: Path, fmt: str) -> None:
        super().__init__(path, scan.source_format or fmt, len(scan), streams=False)
        self._scan: Scan | None = scan

    def _read(self, size: int) -> Generator[Scan, None, None]:
        scan = self._scan
        if scan is None:
            raise ValueError(f"{self.path}: chunks() called after the file was closed")
        for start in range(0, len(scan), size):
            yield _rows(scan, start, start + size)

    def close(self) -> None:
        super().close()
        self._scan = None


def _rows(scan: Scan, start: int, stop: int) -> Scan:
    """Rows ``start:stop`` of ``scan`` as views (no copy)."""
    rows = slice(start, stop)
    return Scan(
        xyz=scan.xyz[rows],
        rgb=None if scan.rgb is None else scan.rgb[rows],
        labels=None if scan.labels is None else scan.labels[rows],
        fields={k: v[rows] for k, v in scan.fields.items()},
        source_format=scan.source_format,
        meta=scan.meta,
    )


def _whole(path: Path, fmt: str, max_points: int, max_inflation: float) -> ScanChunks:
    """The fallback for a file no opener streams: ``read_scan`` once, then slices."""
    scan = read_scan(path, max_points=max_points, max_inflation=max_inflation)
    return _WholeChunks(scan, path, fmt)


def open_chunks(
    path: str | os.PathLike[str],
    *,
    max_points: int = DEFAULT_MAX_POINTS,
    max_inflation: float = DEFAULT_MAX_INFLATION,
) -> ScanChunks:
    """Open a scan file for reading chunk by chunk, with memory bounded by the chunk size.

    How each format is read:

    - **LAS/LAZ**: laspy's chunked reader. :func:`jointseg.io.read_scan` decides some things
      from all points at once (colour whose maximum is ≤ 255 is 8-bit; classification 0
      everywhere in a file not written by jointseg means no labels; odd classification values
      keep the raw values as a field; intensity 0 everywhere is dropped), so a first pass at
      open time gathers those facts. It costs one read of a LAS file; for LAZ with point
      formats 6-10 (what jointseg writes) the x/y, classification, intensity and colour layers
      are decompressed (skipping z, GPS time, extra bytes, ...: roughly half the work of a full
      read); other LAZ files are decompressed whole once more.
    - **Binary PLY**: memory maps of one chunk of vertices at a time. When the vertices have a
      label property or colour that is not 8-bit, a first pass over those columns decides as
      ``read_scan`` does (about one extra read of the file).
    - **Everything else** (ASCII PLY, binary PLY with list elements before the vertices, PLY,
      GLB/glTF and OBJ meshes, PCD, E57, TXT/XYZ/CSV, NPY/NPZ, S3DIS folders): ``read_scan``
      once at open time (a mesh sampled to points), then slices
      of that scan; memory is that of ``read_scan`` (``streams`` is False).

    Parameters
    ----------
    path : str or PathLike
        As for :func:`jointseg.io.read_scan`.
    max_points : int
        Refuse scans with more points, checked from the header before any point is read.
    max_inflation : float
        As for :func:`jointseg.io.read_scan`.

    Returns
    -------
    ScanChunks
        Use it as a context manager; iterate :meth:`ScanChunks.chunks`.

    Raises
    ------
    ScanFormatError
        As :func:`jointseg.io.read_scan`, for what the header and the first pass see (for the
        fallback: for everything). Non-finite coordinates in a streamed file are found when the
        chunk holding them is read.
    """
    path, fmt = prepare_input(path, max_points)
    opener = get_format(fmt).open_chunks
    try:
        chunks = None
        if opener is not None:
            chunks = opener(path, max_points=max_points, max_inflation=max_inflation)
        if chunks is None:
            chunks = _whole(path, fmt, max_points, max_inflation)
    except ScanFormatError:
        raise
    except INPUT_ERRORS as exc:
        raise ScanFormatError(f"{path}: cannot read as {fmt}: {library_reason(exc)}") from exc
    logger.info(
        "opened %s for chunked reading: %d points (%s, %s)",
        path,
        chunks.count,
        chunks.format,
        "streamed" if chunks.streams else "read whole, then sliced",
    )
    return chunks


class _CollectingWriter(ScanWriter):
    """The fallback: chunks are kept and written by ``write_scan`` at the end (not bounded)."""

    streams = False

    def __init__(self, path: Path, fmt: str, count: int, like: Scan) -> None:
        super().__init__(path, fmt, count, like)
        self._template = _rows(like, 0, 0)
        self._chunks: list[Scan] = []

    def _write(self, chunk: Scan) -> None:
        self._chunks.append(chunk)

    def _finish(self) -> None:
        write_scan(_concatenate([self._template, *self._chunks]), self.path)
        self._chunks = []

    def _abort(self) -> None:
        self._chunks = []


def _stack_optional(parts: list[np.ndarray | None]) -> np.ndarray | None:
    present = [p for p in parts if p is not None]
    return np.concatenate(present) if present else None


def _concatenate(chunks: list[Scan]) -> Scan:
    """One scan from chunks that share colour, labels and fields (the first may be empty)."""
    return Scan(
        xyz=np.concatenate([c.xyz for c in chunks]),
        rgb=_stack_optional([c.rgb for c in chunks]),
        labels=_stack_optional([c.labels for c in chunks]),
        fields={k: np.concatenate([c.fields[k] for c in chunks]) for k in chunks[0].fields},
    )


def _check_bounds(bounds: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    try:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"bounds must be (xyz minimum, xyz maximum), got {bounds!r}") from exc
    finite = np.isfinite(lo).all() and np.isfinite(hi).all()
    if lo.shape != (3,) or hi.shape != (3,) or not finite:
        raise ValueError(
            f"bounds must be two finite arrays of shape (3,) (xyz minimum, xyz maximum), "
            f"got {bounds!r}"
        )
    if (lo > hi).any():
        raise ValueError(f"bounds: the minimum {lo.tolist()} exceeds the maximum {hi.tolist()}")
    return lo, hi


def open_writer(
    path: str | os.PathLike[str],
    *,
    count: int,
    like: Scan,
    bounds: tuple[np.ndarray, np.ndarray],
) -> ScanWriter:
    """Open a scan file for writing chunk by chunk, with memory bounded by the chunk size.

    The file is the one :func:`jointseg.io.write_scan` would write from all chunks together:

    - **LAS/LAZ**: the header :func:`jointseg.io.formats.las.core.las_layout` builds for
      ``write_las`` (point format 7/6, scale, offsets at ``bounds``' minimum, extra bytes per
      field, the labels VLR), then laspy's writer, one ``write_points`` per chunk (lazrs for LAZ).
      ``write_las`` puts a field ``intensity`` (``classification``) into LAS's standard
      dimension when it holds whole numbers in 0..65535 (0..255); here ``like``'s values make
      that choice, and a later chunk that does not fit it is refused (uint16 intensity and
      uint8 classification always fit).
    - **PLY**: binary little-endian, the header :func:`jointseg.io.formats.ply.core.write_ply`
      writes (the vertex count is ``count``), then each chunk's records. 64-bit integer fields
      take the property type ``like``'s values give; a chunk whose values do not fit it is
      refused.
    - **Any other format**: the chunks are collected and written by ``write_scan`` at the end,
      so memory is not bounded there (``streams`` is False).

    Parameters
    ----------
    path : str or PathLike
        Target; its extension picks the format, its folder must exist.
    count : int
        Number of points that will be written (PLY needs it in the header; all formats check
        it).
    like : Scan
        A (small) scan with the fields, colour and labels presence and dtypes of every chunk,
        e.g. the first chunk.
    bounds : tuple of (ndarray of shape (3,), ndarray of shape (3,))
        Minimum and maximum coordinates of the whole scan: LAS needs the offsets and scale
        before the first point (other formats do not use them). A LAS chunk whose coordinates
        do not fit 32-bit integers at those offsets and scale is refused.

    Returns
    -------
    ScanWriter
        Use it as a context manager.

    Raises
    ------
    ScanFormatError
        For an extension that cannot be written, a missing folder, or a field the format
        cannot store.
    ValueError
        For a negative ``count`` or malformed ``bounds``.
    """
    path = Path(path)
    prepare_output(path)
    if isinstance(count, bool) or not isinstance(count, int | np.integer) or count < 0:
        raise ValueError(f"count must be a non-negative integer, got {count!r}")
    lo, hi = _check_bounds(bounds)
    fmt = path.suffix.lower()[1:]
    opener = get_format(fmt).open_writer
    if opener is not None:
        return opener(path, count=int(count), like=like, bounds=(lo, hi))
    logger.info(
        "%s: %s is not written in a stream; the chunks are kept in memory and written at the end",
        path,
        fmt,
    )
    return _CollectingWriter(path, fmt, int(count), like)
