"""LAS/LAZ read and written chunk by chunk through laspy (LAZ with lazrs), for big scans.

The per-point conversions are :mod:`jointseg.io.formats.las.core`'s, shared with ``read_las`` and
``write_las``; this module adds the chunked reader with its first pass over the whole file and
the chunked writer. :func:`open_las_chunks` and :class:`LasChunkWriter` are the LAS and LAZ
records' openers in :mod:`jointseg.io.formats`.
"""

from __future__ import annotations

from collections.abc import Generator, Iterator
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import BinaryIO

import laspy
import numpy as np

from jointseg.exceptions import ScanFormatError
from jointseg.io.atomic import atomic_open
from jointseg.io.chunks import (
    DEFAULT_CHUNK_POINTS,
    Bounds,
    FileChunks,
    ScanChunks,
    ScanWriter,
    first_pass,
    joined_sample,
)
from jointseg.io.formats.las.core import (
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
from jointseg.io.limits import check_max_points
from jointseg.scan import Scan

__all__ = ["LasChunkWriter", "open_las_chunks"]

#: What a LAZ first pass decompresses (point formats 6-10; laspy reads everything for others).
_FACTS_SELECTION = (
    laspy.DecompressionSelection.base()
    .decompress_classification()
    .decompress_intensity()
    .decompress_rgb()
)


#: What a LAZ sample decompresses (point formats 6-10): coordinates and colour, nothing else.
_SAMPLE_SELECTION = laspy.DecompressionSelection.base().decompress_z().decompress_rgb()
#: What a pass over the coordinates alone decompresses (point formats 6-10).
_XYZ_SELECTION = laspy.DecompressionSelection.base().decompress_z()


class _LasChunks(FileChunks):
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

    def coordinates(self, size: int = DEFAULT_CHUNK_POINTS) -> Iterator[np.ndarray]:
        """Only a LAZ's coordinate layers decompressed (formats 6-10)."""
        if self._closed:
            raise ValueError(f"{self.path}: coordinates() called after the file was closed")
        self._check_unchanged()
        facts = replace(self._facts, colour=None)  # the colour layer is not read
        with open_reader(self.path, _XYZ_SELECTION) as reader:
            seen = 0
            for points in _las_points(reader, self._header, self.path, size):
                yield points_to_scan(
                    points, self._header, facts, self.path, start=seen, bare=True
                ).xyz
                seen += len(points)

    def _sample(self, stride: int, size: int) -> Scan:
        """Only a LAZ's coordinate and colour layers decompressed (formats 6-10), and only the
        sampled records turned into points: a third of a full pass on a 20 M-point floor."""
        self._check_unchanged()
        xyz, rgb, seen = [], [], 0
        with open_reader(self.path, _SAMPLE_SELECTION) as reader:
            for points in _las_points(reader, self._header, self.path, size):
                first = (-seen) % stride
                picked = points[first::stride]
                if len(picked):
                    part = points_to_scan(
                        picked, self._header, self._facts, self.path, start=seen + first, bare=True
                    )
                    xyz.append(part.xyz)
                    if part.rgb is not None:
                        rgb.append(part.rgb)
                seen += len(points)
        return joined_sample(xyz, rgb, las_meta(self._header), self.format)


def _las_points(
    reader: laspy.LasReader, header: laspy.LasHeader, path: Path, size: int
) -> Iterator[laspy.ScaleAwarePointRecord]:
    """``reader``'s points in chunks of ``size``, with read_las's errors for bad files."""
    batches = reader.chunk_iterator(size)
    read = 0
    while True:
        try:
            points = next(batches)
        except StopIteration:
            break
        except LASPY_ERRORS as exc:
            raise point_read_error(path, header, exc) from exc
        read += len(points)
        yield points
    if read != header.point_count:
        raise short_read_error(path, header, read)


def _las_facts(path: Path, header: laspy.LasHeader, step: int) -> LasFacts:
    """Gather :class:`LasFacts` over the whole file, ``step`` points at a time: colour range,
    classification, intensity.

    For LAZ with point formats 6-10 only the x/y, classification, intensity and colour layers
    are decompressed (and the extra bytes of a result file, whose labels are there); other LAZ
    files are decompressed whole, LAS files read whole.
    """
    facts = LasFacts()
    selection = _FACTS_SELECTION
    if label_source(header.point_format) != "classification":
        selection = selection.decompress_all_extra_bytes()
    with open_reader(path, selection) as reader:
        for points in _las_points(reader, header, path, step):
            facts = facts.merge(las_facts(points, path))
    return facts


def open_las_chunks(path: Path, *, max_points: int, max_inflation: float) -> ScanChunks:
    """A LAS/LAZ file's chunks, after its header's checks and a first pass for whole-file facts.

    ``read_las`` decides colour depth, labels and intensity from all points at once; the first
    pass gathers those facts so that every chunk decides the same. The LAS and LAZ records'
    :class:`~jointseg.io.chunks.ChunkOpener`.
    """
    with open_reader(path) as reader:
        header = reader.header
    check_max_points(header.point_count, max_points, path)
    check_body_size(path, header, max_inflation)
    if header.point_count == 0:
        raise ScanFormatError(f"{path}: the scan contains no points")
    facts = first_pass(
        path,
        header.point_count,
        "points",
        lambda step: _las_facts(path, header, step),
        reader="las",
    )
    log_facts(header, facts, path)
    return _LasChunks(path, header, facts)


class LasChunkWriter(ScanWriter):
    """LAS/LAZ through laspy's writer, one ``write_points`` per chunk.

    The LAS and LAZ records' :class:`~jointseg.io.chunks.WriterOpener`: LAZ by the extension,
    with ``write_las``'s header for ``like``, its offsets and scale from ``bounds``.
    """

    def __init__(self, path: Path, *, count: int, like: Scan, bounds: Bounds) -> None:
        layout = las_layout(like, *bounds, path)
        compress = path.suffix.lower() == ".laz"
        super().__init__(path, "laz" if compress else "las", count, like)
        self._layout: LasLayout = layout
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
