"""Binary PLY read and written chunk by chunk: vertex records mapped or written in place.

The vertex layout and conversions are :mod:`jointseg.io.formats.ply.core`'s, shared with
``read_ply`` and ``write_ply``; this module adds the chunked reader (memory maps of one chunk of
vertices, with a first pass where whole-file facts decide) and the chunked writer.
:func:`open_ply_chunks` and
:class:`PlyChunkWriter` are the PLY record's openers in :mod:`jointseg.io.formats`.
"""

from __future__ import annotations

from collections.abc import Generator, Iterator
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from jointseg.exceptions import ScanFormatError
from jointseg.io.atomic import atomic_open
from jointseg.io.build import build_scan
from jointseg.io.chunks import Bounds, FileChunks, ScanChunks, ScanWriter, first_pass
from jointseg.io.colour import check_colour_range
from jointseg.io.formats.ply.core import (
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
from jointseg.io.labels import log_outside_labels
from jointseg.io.limits import check_max_points
from jointseg.scan import Scan

__all__ = ["PlyChunkWriter", "open_ply_chunks"]


class _PlyChunks(FileChunks):
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

    def gather_facts(self, step: int) -> VertexFacts:
        """Gather :class:`VertexFacts` (colour range, odd labels) over every vertex, ``step`` at
        a time.

        Reads the colour and label columns of every vertex once, which pages in the whole
        vertex block: about one extra read of the file.
        """
        facts = VertexFacts()
        for start, window in self.windows(step):
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


def open_ply_chunks(path: Path, *, max_points: int, max_inflation: float) -> ScanChunks | None:
    """A binary PLY's vertex chunks; None for a mesh, ASCII, or list elements before the vertices.

    Those are read whole by the fallback. ``max_inflation`` does not apply: a PLY body is not
    compressed. The PLY record's :class:`~jointseg.io.chunks.ChunkOpener`.
    """
    header = probe_header(path)
    vertex = vertex_element(header, path)
    if header.faces:  # a mesh: its points are sampled on the faces, whole
        return None
    check_max_points(vertex.count, max_points, path)
    if header.encoding == "ascii":
        return None
    block = binary_vertex_block(path, header)
    if block is None:  # list elements before the vertices: only plyfile finds them
        return None
    if vertex.count == 0:
        raise ScanFormatError(f"{path}: the scan contains no points")
    offset, dtype = block
    chunks = _PlyChunks(path, vertex.count, offset, dtype, header.meta)
    if _ply_needs_facts(dtype):
        facts = first_pass(path, vertex.count, "vertices", chunks.gather_facts, reader="ply")
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


class PlyChunkWriter(ScanWriter):
    """Binary little-endian PLY: the header for ``count`` vertices, then each chunk's records.

    The PLY record's :class:`~jointseg.io.chunks.WriterOpener`, with ``write_ply``'s header for
    ``like``; ``bounds`` are not needed, PLY stores coordinates as they are.
    """

    def __init__(self, path: Path, *, count: int, like: Scan, bounds: Bounds) -> None:
        layout = ply_layout(like, path)
        super().__init__(path, "ply", count, like)
        self._layout: PlyLayout = layout
        self._fh: BinaryIO | None = None

    def _begin(self, stack: ExitStack) -> None:
        self._fh = stack.enter_context(atomic_open(self.path))
        self._fh.write(self._layout.header(self.count))

    def _write(self, chunk: Scan) -> None:
        assert self._fh is not None
        self._layout.write(self._fh, chunk, self.path)

    def _finish(self) -> None:
        self._fh = None

    def _abort(self) -> None:
        self._fh = None
