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
import time
import weakref
from collections.abc import Generator, Iterator
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import laspy
import numpy as np

from jointseg.exceptions import ConfigError, ScanFormatError, library_reason
from jointseg.io import read_scan, write_scan
from jointseg.io.atomic import atomic_open
from jointseg.io.build import build_scan
from jointseg.io.colour import check_colour_range
from jointseg.io.dispatch import INPUT_ERRORS, prepare_input, prepare_output
from jointseg.io.labels import log_outside_labels
from jointseg.io.las import (
    LASPY_ERRORS,
    LasFacts,
    LasLayout,
    check_body_size,
    check_layout_fits,
    label_source,
    las_facts,
    las_layout,
    las_meta,
    las_record,
    laz_backend,
    log_facts,
    open_reader,
    point_read_error,
    points_to_scan,
    short_read_error,
)
from jointseg.io.limits import DEFAULT_MAX_INFLATION, DEFAULT_MAX_POINTS, check_max_points
from jointseg.io.ply import (
    PlyLayout,
    VertexFacts,
    binary_vertex_block,
    ply_layout,
    probe_header,
    split_vertex,
    vertex_columns,
    vertex_element,
    vertex_facts,
)
from jointseg.scan import Scan

__all__ = ["DEFAULT_CHUNK_POINTS", "ScanChunks", "ScanWriter", "open_chunks", "open_writer"]

logger = logging.getLogger(__name__)

#: Points per chunk when :meth:`ScanChunks.chunks` is given no size.
DEFAULT_CHUNK_POINTS = 1_000_000
#: Points per step of the first pass that gathers whole-file facts (bounded memory there too).
_PASS_POINTS = 250_000
#: What a LAZ first pass decompresses (point formats 6-10; laspy reads everything for others).
_FACTS_SELECTION = (
    laspy.DecompressionSelection.base()
    .decompress_classification()
    .decompress_intensity()
    .decompress_rgb()
)


def _identity(path: Path) -> tuple[int, ...]:
    st = os.stat(path)
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


class ScanChunks:
    """A scan file opened for reading in chunks; returned by :func:`open_chunks`.

    A context manager: leaving the block (or :meth:`close`) stops every iteration still
    running and closes its file.

    Attributes
    ----------
    path : Path
        The file.
    format : str
        Format name as in :mod:`jointseg.io.formats` (``"laz"`` for a compressed LAS file
        whatever its extension, as ``read_scan`` says in ``source_format``).
    count : int
        Number of points in the file.
    streams : bool
        True when chunks are read from the file as they are asked for (LAS/LAZ, binary PLY);
        False when the whole scan was read at open time and chunks are slices of it.
    """

    def __init__(self, path: Path, fmt: str, count: int, *, streams: bool) -> None:
        self.path = path
        self.format = fmt
        self.count = count
        self.streams = streams
        self._closed = False
        self._running: weakref.WeakSet[Generator[Scan, None, None]] = weakref.WeakSet()

    def chunks(self, size: int = DEFAULT_CHUNK_POINTS) -> Iterator[Scan]:
        """Consecutive chunks of the scan, in file order, from the beginning of the file.

        Each chunk is a :class:`Scan` with the same fields, dtypes and colour/label decisions as
        the whole ``read_scan`` result, whose rows it holds; every chunk has ``size`` points but
        the last. Can be called again (also while another iteration runs) to start over.

        Parameters
        ----------
        size : int
            Points per chunk (≥ 1).

        Returns
        -------
        iterator of Scan

        Raises
        ------
        ConfigError
            When ``size`` is not a positive integer.
        ValueError
            After :meth:`close`.
        ScanFormatError
            While iterating: when the file changed since it was opened, is truncated or
            corrupt (LAZ), or holds non-finite coordinates (the message names the point).
        """
        if self._closed:
            raise ValueError(f"{self.path}: chunks() called after the file was closed")
        if isinstance(size, bool) or not isinstance(size, int | np.integer) or size < 1:
            raise ConfigError(f"chunk size must be a positive integer, got {size!r}")
        iteration = self._guarded(int(size))
        self._running.add(iteration)
        return iteration

    def close(self) -> None:
        """Stop the iterations still running (closing their files)."""
        for iteration in list(self._running):
            iteration.close()
        self._closed = True

    def __enter__(self) -> ScanChunks:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def _read(self, size: int) -> Generator[Scan, None, None]:
        raise NotImplementedError

    def _guarded(self, size: int) -> Generator[Scan, None, None]:
        """Run :meth:`_read`, turning library errors into ScanFormatError and counting points."""
        read = 0
        source = self._read(size)
        try:
            while True:
                try:
                    chunk = next(source)
                except StopIteration:
                    break
                except ScanFormatError:
                    raise
                except INPUT_ERRORS as exc:
                    raise ScanFormatError(
                        f"{self.path}: cannot read as {self.format}: {library_reason(exc)}"
                    ) from exc
                read += len(chunk)
                yield chunk
        finally:
            source.close()
        if read != self.count:
            raise ScanFormatError(
                f"{self.path}: truncated file: {self.count:,} points were declared but only "
                f"{read:,} could be read"
            )


class _FileChunks(ScanChunks):
    """Chunks read from the file itself; refuses to go on when the file changed since open."""

    def __init__(self, path: Path, fmt: str, count: int) -> None:
        super().__init__(path, fmt, count, streams=True)
        self._identity = _identity(path)

    def _check_unchanged(self) -> None:
        if _identity(self.path) != self._identity:
            raise ScanFormatError(
                f"{self.path}: the file changed since it was opened for reading in chunks; "
                f"open it again"
            )


class _LasChunks(_FileChunks):
    """LAS/LAZ through laspy's chunked reader, with whole-file facts from a first pass."""

    def __init__(self, path: Path, header: laspy.LasHeader, facts: LasFacts) -> None:
        fmt = "laz" if header.are_points_compressed else "las"
        super().__init__(path, fmt, header.point_count)
        self._header = header
        self._facts = facts

    def _read(self, size: int) -> Generator[Scan, None, None]:
        self._check_unchanged()
        start = 0
        meta = las_meta(self._header)
        with open_reader(self.path) as reader:
            for points in _las_points(reader, self._header, self.path, size):
                scan = points_to_scan(points, self._header, self._facts, self.path, start=start)
                yield replace(scan, meta=meta)
                start += len(points)


def _las_points(
    reader: laspy.LasReader, header: laspy.LasHeader, path: Path, size: int
) -> Iterator[laspy.ScaleAwarePointRecord]:
    """``reader``'s points in chunks of ``size``, with read_las's errors for bad files."""
    chunks = reader.chunk_iterator(size)
    read = 0
    while True:
        try:
            points = next(chunks)
        except StopIteration:
            break
        except LASPY_ERRORS as exc:
            raise point_read_error(path, header, exc) from exc
        read += len(points)
        yield points
    if read != header.point_count:
        raise short_read_error(path, header, read)


def _las_first_pass(path: Path, header: laspy.LasHeader) -> LasFacts:
    """Gather :class:`LasFacts` over the whole file: colour range, classification, intensity.

    For LAZ with point formats 6-10 only the x/y, classification, intensity and colour layers
    are decompressed (and the extra bytes of a result file, whose labels are there); other LAZ
    files are decompressed whole, LAS files read whole.
    """
    facts = LasFacts()
    selection = _FACTS_SELECTION
    if label_source(header.point_format) != "classification":
        selection = selection.decompress_all_extra_bytes()
    with open_reader(path, selection) as reader:
        for points in _las_points(reader, header, path, _PASS_POINTS):
            facts = facts.merge(las_facts(points, path))
    return facts


def _open_las(path: Path, max_points: int, max_inflation: float) -> ScanChunks:
    with open_reader(path) as reader:
        header = reader.header
    check_max_points(header.point_count, max_points, path)
    check_body_size(path, header, max_inflation)
    if header.point_count == 0:
        raise ScanFormatError(f"{path}: the scan contains no points")
    began = time.perf_counter()
    facts = _las_first_pass(path, header)
    logger.debug(
        "%s: first pass over %d points in %.2f s",
        path,
        header.point_count,
        time.perf_counter() - began,
    )
    log_facts(header, facts, path)
    return _LasChunks(path, header, facts)


class _PlyChunks(_FileChunks):
    """Binary PLY vertices through a memory map of one chunk at a time.

    Each chunk maps only its own rows, and the map is dropped with the chunk: a map of the
    whole file would keep every page it has touched resident (and counted in the process's
    memory) until the iteration ends.
    """

    def __init__(
        self, path: Path, count: int, offset: int, dtype: np.dtype, meta: dict[str, Any]
    ) -> None:
        super().__init__(path, "ply", count)
        self._offset = offset
        self._dtype = dtype
        self._facts = VertexFacts()
        self._meta = meta

    def gather_facts(self) -> VertexFacts:
        """Gather :class:`VertexFacts` (colour range, odd labels) over every vertex.

        Reads the colour and label columns of every vertex once, which pages in the whole
        vertex block: about one extra read of the file.
        """
        facts = VertexFacts()
        for start, window in self.windows(_PASS_POINTS):
            facts = facts.merge(vertex_facts(window, self.path, start=start))
        self._facts = facts
        return facts

    def window(self, start: int, n: int) -> np.ndarray:
        """Vertices ``start .. start + n - 1`` as a read-only structured memory map."""
        self._check_unchanged()
        offset = self._offset + start * self._dtype.itemsize
        return np.memmap(self.path, dtype=self._dtype, mode="r", offset=offset, shape=(n,))

    def windows(self, size: int) -> Iterator[tuple[int, np.ndarray]]:
        """``(start, window)`` over every vertex, ``size`` at a time."""
        for start in range(0, self.count, size):
            yield start, self.window(start, min(size, self.count - start))

    def _read(self, size: int) -> Generator[Scan, None, None]:
        for start, window in self.windows(size):
            xyz, rgb, labels, fields = split_vertex(window, self.path, self._facts, start=start)
            del window
            scan = build_scan(self.path, "ply", xyz, rgb, labels, fields, start=start)
            yield replace(scan, meta=self._meta)


def _ply_needs_facts(dtype: np.dtype) -> bool:
    """Whether reading chunks needs whole-file facts: labels, or colour other than uint8."""
    colour, label = vertex_columns(list(dtype.names or ()))
    return label is not None or (colour is not None and any(dtype[c] != np.uint8 for c in colour))


def _open_ply(path: Path, max_points: int) -> ScanChunks:
    header = probe_header(path)
    vertex = vertex_element(header, path)
    if header.faces:  # a mesh: its points are sampled on the faces, whole
        return _whole(path, "ply", max_points)
    check_max_points(vertex.count, max_points, path)
    if header.encoding == "ascii":
        return _whole(path, "ply", max_points)
    block = binary_vertex_block(path, header)
    if block is None:  # list elements before the vertices: only plyfile finds them
        return _whole(path, "ply", max_points)
    if vertex.count == 0:
        raise ScanFormatError(f"{path}: the scan contains no points")
    offset, dtype = block
    chunks = _PlyChunks(path, vertex.count, offset, dtype, header.meta)
    if _ply_needs_facts(dtype):
        began = time.perf_counter()
        facts = chunks.gather_facts()
        logger.debug(
            "%s: first pass over %d vertices in %.2f s",
            path,
            vertex.count,
            time.perf_counter() - began,
        )
        _check_ply_facts(path, dtype, facts)
    return chunks


def _check_ply_facts(path: Path, dtype: np.dtype, facts: VertexFacts) -> None:
    """Raise and warn, once per file, as read_ply would on the whole colour and label columns."""
    colour, label = vertex_columns(list(dtype.names or ()))
    if colour is not None and facts.colour is not None:
        what = "colour " + "/".join(colour)
        check_colour_range(dtype[colour[0]].kind, facts.colour, path=path, what=what)
    if label is not None and facts.labels is not None:
        log_outside_labels(facts.labels, path=path, source=label, raw_field="raw_label")


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


def _whole(
    path: Path, fmt: str, max_points: int, max_inflation: float = DEFAULT_MAX_INFLATION
) -> ScanChunks:
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
    try:
        if fmt in ("las", "laz"):
            chunks = _open_las(path, max_points, max_inflation)
        elif fmt == "ply":
            chunks = _open_ply(path, max_points)
        else:
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


def _signature(scan: Scan) -> dict[str, object]:
    """What every chunk written must share with ``like``: colour, labels, field dtypes."""
    return {
        "rgb": scan.rgb is not None,
        "labels": scan.labels is not None,
        **{f"field {name!r}": (v.dtype.str, v.shape[1:]) for name, v in scan.fields.items()},
    }


class ScanWriter:
    """A scan file being written chunk by chunk; returned by :func:`open_writer`.

    Use it as a context manager and call :meth:`write` inside the block. Leaving the block
    normally completes the file and renames it into place atomically; leaving it by an
    exception (or with fewer points than promised) leaves nothing at the target.

    Attributes
    ----------
    path : Path
        The target.
    format : str
        Format name from the extension.
    count : int
        Points promised.
    written : int
        Points written so far.
    streams : bool
        True when chunks go to the file as they come (LAS/LAZ, PLY); False when they are
        collected and written at the end.
    """

    streams = True

    def __init__(self, path: Path, fmt: str, count: int, like: Scan) -> None:
        self.path = path
        self.format = fmt
        self.count = count
        self.written = 0
        self._like = _signature(like)
        self._stack: ExitStack | None = None
        self._state = "new"

    def __enter__(self) -> ScanWriter:
        if self._state != "new":
            raise ValueError(f"{self.path}: a ScanWriter can be used for one with-block only")
        stack = ExitStack()
        try:
            self._begin(stack)
        except BaseException as exc:
            stack.__exit__(type(exc), exc, exc.__traceback__)
            raise
        self._stack = stack
        self._state = "open"
        return self

    def write(self, chunk: Scan) -> None:
        """Append ``chunk``'s points.

        Raises
        ------
        ValueError
            Outside the with-block, when the chunk's colour, labels or fields (names, dtypes)
            differ from ``like``'s, or when it would exceed ``count``.
        ScanFormatError
            When the format cannot store the chunk's values in the layout chosen from ``like``
            (see :func:`open_writer`).
        """
        if self._state != "open":
            raise ValueError(f"{self.path}: write() outside the writer's with-block")
        got = _signature(chunk)
        if got != self._like:
            keys = got.keys() | self._like.keys()
            diff = sorted(k for k in keys if got.get(k) != self._like.get(k))
            raise ValueError(
                f"{self.path}: the chunk at point {self.written:,} differs from `like` in "
                f"{', '.join(diff)}; every chunk needs the same colour, labels and fields "
                f"(names and dtypes)"
            )
        if self.written + len(chunk) > self.count:
            raise ValueError(
                f"{self.path}: writing {len(chunk):,} more points after {self.written:,} would "
                f"exceed count={self.count:,}"
            )
        self._write(chunk)
        self.written += len(chunk)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        stack, self._stack, self._state = self._stack, None, "done"
        assert stack is not None
        if exc is not None:
            self._abort()
            stack.__exit__(exc_type, exc, tb)
            return
        try:
            if self.written != self.count:
                raise ValueError(
                    f"{self.path}: {self.written:,} points were written but count={self.count:,} "
                    f"was promised; nothing was written"
                )
            self._finish()
        except BaseException as err:
            self._abort()
            stack.__exit__(type(err), err, err.__traceback__)
            raise
        stack.close()  # renames the finished file into place
        logger.info("wrote %s: %d points in chunks", self.path, self.written)

    def _begin(self, stack: ExitStack) -> None:
        """Open the target (registering its clean-up on ``stack``) and write a header."""

    def _write(self, chunk: Scan) -> None:
        raise NotImplementedError

    def _finish(self) -> None:
        """Complete the file (before it is renamed into place)."""

    def _abort(self) -> None:
        """Drop what was written (the temporary file itself is removed by the stack)."""


class _LasWriter(ScanWriter):
    """LAS/LAZ through laspy's writer, one ``write_points`` per chunk."""

    def __init__(self, path: Path, count: int, like: Scan, layout: LasLayout) -> None:
        compress = path.suffix.lower() == ".laz"
        super().__init__(path, "laz" if compress else "las", count, like)
        self._layout = layout
        self._compress = compress
        self._las: laspy.LasWriter | None = None

    def _begin(self, stack: ExitStack) -> None:
        fh: BinaryIO = stack.enter_context(atomic_open(self.path))
        self._las = laspy.LasWriter(
            fh,
            self._layout.header,
            do_compress=self._compress,
            laz_backend=laz_backend(self._compress),
            closefd=False,
        )

    def _write(self, chunk: Scan) -> None:
        assert self._las is not None
        check_layout_fits(chunk, self._layout, self.path)
        try:
            self._las.write_points(las_record(chunk, self._layout, self.path))
        except laspy.errors.LaspyException as exc:
            raise ScanFormatError(f"{self.path}: cannot write LAS: {exc}") from exc

    def _finish(self) -> None:
        assert self._las is not None
        try:
            self._las.close()  # the LAZ chunk table and the header's counts and bounds
        except laspy.errors.LaspyException as exc:
            raise ScanFormatError(f"{self.path}: cannot write LAS: {exc}") from exc
        self._las = None

    def _abort(self) -> None:
        self._las = None


class _PlyWriter(ScanWriter):
    """Binary little-endian PLY: the header for ``count`` vertices, then each chunk's records."""

    def __init__(self, path: Path, count: int, like: Scan, layout: PlyLayout) -> None:
        super().__init__(path, "ply", count, like)
        self._layout = layout
        self._fh: BinaryIO | None = None

    def _begin(self, stack: ExitStack) -> None:
        self._fh = stack.enter_context(atomic_open(self.path))
        self._fh.write(self._layout.header(self.count))

    def _write(self, chunk: Scan) -> None:
        assert self._fh is not None
        self._fh.write(self._layout.record(chunk, self.path).tobytes())

    def _finish(self) -> None:
        self._fh = None

    def _abort(self) -> None:
        self._fh = None


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

    - **LAS/LAZ**: the header :func:`jointseg.io.las.las_layout` builds for ``write_las``
      (point format 7/6, scale, offsets at ``bounds``' minimum, extra bytes per field, the
      labels VLR), then laspy's writer, one ``write_points`` per chunk (lazrs for LAZ).
      ``write_las`` puts a field ``intensity`` (``classification``) into LAS's standard
      dimension when it holds whole numbers in 0..65535 (0..255); here ``like``'s values make
      that choice, and a later chunk that does not fit it is refused (uint16 intensity and
      uint8 classification always fit).
    - **PLY**: binary little-endian, the header :func:`jointseg.io.ply.write_ply` writes (the
      vertex count is ``count``), then each chunk's records. 64-bit integer fields take the
      property type ``like``'s values give; a chunk whose values do not fit it is refused.
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
    if fmt in ("las", "laz"):
        writer: ScanWriter = _LasWriter(path, int(count), like, las_layout(like, lo, hi, path))
    elif fmt == "ply":
        writer = _PlyWriter(path, int(count), like, ply_layout(like, path))
    else:
        writer = _CollectingWriter(path, fmt, int(count), like)
        logger.info(
            "%s: %s is not written in a stream; the chunks are kept in memory and written at "
            "the end",
            path,
            fmt,
        )
    return writer
