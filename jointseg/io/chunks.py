"""What chunked reading and writing share, whatever the format: the types and the protocols.

:class:`ScanChunks` and :class:`ScanWriter` are what :func:`jointseg.io.stream.open_chunks` and
:func:`jointseg.io.stream.open_writer` return; a format that streams subclasses them in its own
module (:mod:`jointseg.io.formats.las.stream`, :mod:`jointseg.io.formats.ply.stream`) and
names its openers, :class:`ChunkOpener` and :class:`WriterOpener`, in its
:class:`~jointseg.io.formats.Format` record. Kept apart from :mod:`jointseg.io.stream` (which reads
the formats without an opener through :func:`jointseg.io.read_scan`) so that the format table can
import the openers without an import cycle.
"""

from __future__ import annotations

import logging
import os
import time
import weakref
from collections.abc import Callable, Generator, Iterator
from contextlib import ExitStack
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, TypeVar

import numpy as np

from jointseg.exceptions import ConfigError, ScanFormatError, library_reason
from jointseg.io.limits import INPUT_ERRORS
from jointseg.lru import LRUCache
from jointseg.scan import Scan

__all__ = [
    "DEFAULT_CHUNK_POINTS",
    "PASS_POINTS",
    "Bounds",
    "ChunkOpener",
    "FileChunks",
    "ScanChunks",
    "ScanWriter",
    "WriterOpener",
    "first_pass",
]

logger = logging.getLogger(__name__)

T = TypeVar("T")

#: Points per chunk when :meth:`ScanChunks.chunks` is given no size.
DEFAULT_CHUNK_POINTS = 1_000_000
#: Points per step of a first pass that gathers whole-file facts (bounded memory there too).
PASS_POINTS = 250_000

#: A whole scan's xyz minimum and maximum, each of shape (3,): LAS needs its offsets up front.
Bounds = tuple[np.ndarray, np.ndarray]


class ChunkOpener(Protocol):
    """How a format opens a file for chunked reading: its ``Format.open_chunks``."""

    def __call__(self, path: Path, *, max_points: int, max_inflation: float) -> ScanChunks | None:
        """The file's chunks, read as they are asked for; None when this file cannot be.

        None (a PLY mesh, an ASCII PLY) sends the file to the fallback that reads it whole.
        ``path`` has been checked and its format picked by
        :func:`jointseg.io.dispatch.prepare_input`.
        """


class WriterOpener(Protocol):
    """How a format opens a target for chunked writing: its ``Format.open_writer``.

    A :class:`ScanWriter` subclass whose constructor takes these arguments is one.
    """

    def __call__(self, path: Path, *, count: int, like: Scan, bounds: Bounds) -> ScanWriter:
        """A writer for ``count`` points shaped like ``like``.

        :func:`jointseg.io.stream.open_writer` has checked the target, ``count`` and ``bounds``
        (float64, finite, minimum ≤ maximum) before.
        """


#: Files whose whole-file facts are remembered at once (the least recently used forgotten).
PASSED_FILES = 8
#: Whole-file facts of the files passed over lately, by reader and the file's identity: a tiled
#: run opens its input four times (frame, spill, fusion, outputs), and each pass over a 20 M-point
#: LAZ decompresses it whole (4.6 s of a 5 M-point floor's 11.6 s prepare step).
_PASSED: LRUCache[tuple[object, ...], object] = LRUCache(PASSED_FILES)


def first_pass(path: Path, count: int, unit: str, gather: Callable[[int], T], *, reader: str) -> T:
    """Run ``gather``, a first pass over the whole file for whole-file facts, logging its time;
    the facts of a file ``reader`` passed over before and that has not changed since (same
    device, inode, size and mtime) are not gathered again.

    ``gather`` steps through the file :data:`PASS_POINTS` at a time, so the pass is bounded in
    memory like the chunks; it costs about one more read of the file, worth seeing in the log.
    """

    def run() -> object:
        began = time.perf_counter()
        facts = gather(PASS_POINTS)
        logger.debug(
            "%s: first pass over %d %s in %.2f s", path, count, unit, time.perf_counter() - began
        )
        return facts

    key = (reader, os.path.abspath(path), *_file_identity(path))
    return _PASSED.get_or_load(key, run)  # type: ignore[return-value]


def _file_identity(path: Path) -> tuple[int, ...]:
    """What changes when a file is replaced or rewritten: device, inode, size, mtime."""
    st = os.stat(path)
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


class ScanChunks:
    """A scan file opened for reading in chunks; returned by
    :func:`~jointseg.io.stream.open_chunks`.

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

    def sample(self, stride: int, size: int = DEFAULT_CHUNK_POINTS) -> Scan:
        """Every ``stride``-th point of the file (points 0, stride, 2 stride, ...): coordinates
        and colour as :meth:`chunks` gives them, no labels or fields, the file's ``meta``.

        Why not :meth:`chunks` and a slice: a format can skip what the sample does not need
        (a LAZ file's other layers, the records between the sampled ones), and a tiled run's
        frame looks at a sample of every file before it reads the file whole.
        """
        if self._closed:
            raise ValueError(f"{self.path}: sample() called after the file was closed")
        if isinstance(stride, bool) or not isinstance(stride, int | np.integer) or stride < 1:
            raise ConfigError(f"sample stride must be a positive integer, got {stride!r}")
        return self._sample(int(stride), size)

    def coordinates(self, size: int = DEFAULT_CHUNK_POINTS) -> Iterator[np.ndarray]:
        """The points' coordinates (n, 3) float64 in chunks of ``size``, in file order: the
        ``xyz`` of :meth:`chunks`, for a pass that needs nothing else (a LAZ file's other
        layers are then not decompressed: its objects pass over a 20 M-point floor)."""
        for chunk in self.chunks(size):
            yield chunk.xyz

    def _sample(self, stride: int, size: int) -> Scan:
        xyz, rgb, seen = [], [], 0
        meta: dict[str, Any] = {}
        for chunk in self.chunks(size):
            first = (-seen) % stride
            xyz.append(chunk.xyz[first::stride])
            if chunk.rgb is not None:
                rgb.append(chunk.rgb[first::stride])
            meta = meta or dict(chunk.meta)
            seen += len(chunk)
        return joined_sample(xyz, rgb, meta, self.format)

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


class FileChunks(ScanChunks):
    """Chunks read from the file itself; refuses to go on when the file changed since open."""

    def __init__(self, path: Path, fmt: str, count: int) -> None:
        super().__init__(path, fmt, count, streams=True)
        self._identity = _file_identity(path)

    def _check_unchanged(self) -> None:
        if _file_identity(self.path) != self._identity:
            raise ScanFormatError(
                f"{self.path}: the file changed since it was opened for reading in chunks; "
                f"open it again"
            )


def joined_sample(
    xyz: list[np.ndarray], rgb: list[np.ndarray], meta: dict[str, Any], fmt: str
) -> Scan:
    """A sample's parts as one scan (colour only when every part had it)."""
    colour = np.concatenate(rgb) if rgb and len(rgb) == len(xyz) else None
    points = np.concatenate(xyz) if xyz else np.zeros((0, 3))
    return Scan(points, colour, meta=meta, source_format=fmt)


def _signature(scan: Scan) -> dict[str, object]:
    """What every chunk written must share with ``like``: colour, labels, field dtypes."""
    return {
        "rgb": scan.rgb is not None,
        "labels": scan.labels is not None,
        **{f"field {name!r}": (v.dtype.str, v.shape[1:]) for name, v in scan.fields.items()},
    }


class ScanWriter:
    """A scan file being written chunk by chunk; returned by
    :func:`~jointseg.io.stream.open_writer`.

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
            (see :func:`~jointseg.io.stream.open_writer`).
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
