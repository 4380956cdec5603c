"""Chosen columns of chosen vertices of a binary PLY, read block by block into one reused buffer.

For a caller that needs a few columns of a big file (the viewer: the labels of every vertex and
the xyz of a sample), neither :func:`jointseg.io.read_scan` (the whole file in memory, every
column converted) nor :mod:`jointseg.io.stream` (every column of every chunk converted) fits:
here memory is one block, whatever the size of the file, and values stay as stored.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError
from jointseg.io.formats.ply.core import probe_header, vertex_element, vertex_offset


@dataclass(frozen=True, eq=False)
class VertexBlock:
    """Consecutive vertex records held in the reader's buffer, valid until the next block.

    Attributes
    ----------
    start : int
        Index of the block's first vertex in the file.
    records : structured ndarray of shape (n,)
        The block's records in the file's dtype (a view of the buffer).
    raw : ndarray of shape (n, itemsize), uint8
        The same records as bytes (the buffer itself).
    """

    start: int
    records: np.ndarray
    raw: np.ndarray

    def column(self, name: str) -> np.ndarray:
        """Property ``name`` of every vertex of the block (a view of the buffer)."""
        return self.records[name]

    def take(self, rows: np.ndarray, names: Sequence[str]) -> dict[str, np.ndarray]:
        """Properties ``names`` of the vertices at ``rows`` (indices within the block), copied.

        The records are gathered as bytes first: numpy's take on a 2-D byte array is several
        times faster than fancy indexing of a structured one.
        """
        part = np.take(self.raw, rows, axis=0).view(self.records.dtype).reshape(len(rows))
        return {name: part[name] for name in names}


@dataclass(frozen=True)
class VertexBlocks:
    """The vertex records of a binary PLY; returned by :func:`open_vertex_blocks`.

    Attributes
    ----------
    path : Path
    count : int
        Vertices declared by the header.
    offset : int
        Byte offset of the first vertex record.
    dtype : numpy.dtype
        The structured record, in the file's byte order.
    """

    path: Path
    count: int
    offset: int
    dtype: np.dtype

    @property
    def names(self) -> list[str]:
        """The vertex properties, in file order."""
        return list(self.dtype.names or ())

    def blocks(self, block_bytes: int) -> Iterator[VertexBlock]:
        """Every vertex, in file order, about ``block_bytes`` at a time (at least one vertex).

        The file's size is checked here, before any block is read; each block overwrites the
        previous one's buffer.

        Raises
        ------
        ScanFormatError
            When the file is shorter than the header's vertices need (here, or while
            iterating when the file shrank since).
        """
        need = self.offset + self.count * self.dtype.itemsize
        size = os.path.getsize(self.path)
        if size < need:
            raise ScanFormatError(
                f"{self.path}: truncated PLY: the header declares {self.count:,} vertices "
                f"({need:,} bytes with the header) but the file has {size:,}"
            )
        return self._blocks(max(1, block_bytes // self.dtype.itemsize))

    def _blocks(self, block_rows: int) -> Iterator[VertexBlock]:
        itemsize = self.dtype.itemsize
        buffer = np.empty((min(block_rows, max(self.count, 1)), itemsize), dtype=np.uint8)
        records = buffer.view(self.dtype).reshape(buffer.shape[0])
        with open(self.path, "rb") as fh:
            fh.seek(self.offset)
            start = 0
            while start < self.count:
                n = min(block_rows, self.count - start)
                got = fh.readinto(buffer[:n].data.cast("B"))
                if got != n * itemsize:  # the file shrank after the size check
                    raise ScanFormatError(
                        f"{self.path}: truncated PLY: vertex {start + got // itemsize:,} of "
                        f"{self.count:,} is cut short"
                    )
                yield VertexBlock(start, records[:n], buffer[:n])
                start += n


def open_vertex_blocks(path: Path) -> VertexBlocks | None:
    """The vertex records of a binary PLY, to read by blocks (see :meth:`VertexBlocks.blocks`).

    Returns
    -------
    VertexBlocks or None
        None for an ASCII PLY, or when an element with list properties comes before the
        vertices (their offset is unknown without parsing it): read those with
        :func:`jointseg.io.read_scan`.

    Raises
    ------
    ScanFormatError
        On a bad header (as :func:`jointseg.io.read_scan`).
    """
    header = probe_header(path)
    if header.encoding == "ascii":
        return None
    vertex = vertex_element(header, path)
    offset = vertex_offset(header, path)
    if offset is None:
        return None
    return VertexBlocks(path, vertex.count, offset, vertex.dtype(header.byte_order))
