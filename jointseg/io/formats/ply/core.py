"""PLY (ASCII, binary little- and big-endian): header parsed here, body read with numpy.

Reading takes the ``vertex`` element: ``x y z``; colour from ``red green blue``, ``r g b`` or
``diffuse_red diffuse_green diffuse_blue`` (uchar kept, ushort divided by 257 unless all ≤ 255,
float 0–1 scaled); labels from ``label``, ``class``, ``classification``,
``scalar_Classification`` or ``scalar_label`` (case-insensitive); every other vertex property
becomes a field of the same name and dtype. Other elements are ignored here; a PLY whose header
declares faces is a mesh, which :func:`jointseg.io.formats.read_ply_file` reads as points sampled
on its faces. The header's ``comment`` and ``obj_info`` lines go to
``Scan.meta["comments"]``.

Writing produces binary little-endian PLY: ``x y z`` double, ``red green blue`` uchar, ``label``
int, then every field. PLY properties are scalars, so a 2-D field ``f`` of width k is written as
``f_0 .. f_{k-1}`` and reads back as those 1-D fields.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import BinaryIO

import numpy as np

from jointseg.exceptions import ScanFormatError, library_reason
from jointseg.io.atomic import atomic_open
from jointseg.io.build import build_scan
from jointseg.io.colour import ColourRange, colour_range, merge_colour_ranges, to_rgb8
from jointseg.io.columns import LABEL_NAMES, pick_colour_names, pick_name
from jointseg.io.fields import FieldColumn, field_columns, narrow_dtype, narrow_like
from jointseg.io.labels import LabelSummary, label_summary, normalise_labels
from jointseg.io.limits import ScanInfo, check_max_points
from jointseg.io.tabular import parse_table
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

#: PLY type names (both spellings) to numpy type codes.
PLY_TYPES: dict[str, str] = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_WRITE_TYPES = {
    "i1": "char",
    "u1": "uchar",
    "i2": "short",
    "u2": "ushort",
    "i4": "int",
    "u4": "uint",
    "f4": "float",
    "f8": "double",
}
_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_MAX_HEADER_BYTES = 1 << 20


@dataclass
class PlyProperty:
    """One property of a PLY element: scalar (``dtype``) or list (``count_dtype`` + ``dtype``)."""

    name: str
    dtype: str
    count_dtype: str | None = None


@dataclass
class PlyElement:
    """One element declaration: name, instance count and properties."""

    name: str
    count: int
    line: int
    properties: list[PlyProperty] = field(default_factory=list)

    @property
    def fixed_size(self) -> bool:
        """Whether every instance has the same byte size (no list properties)."""
        return all(p.count_dtype is None for p in self.properties)

    def dtype(self, order: str) -> np.dtype:
        """Structured dtype of one instance (binary formats, fixed-size elements only)."""
        return np.dtype([(p.name, order + p.dtype) for p in self.properties])


@dataclass
class PlyHeader:
    """The parsed header: encoding, elements, and where the body starts."""

    encoding: str
    elements: list[PlyElement]
    body_offset: int
    n_lines: int
    comments: list[str] = field(default_factory=list)

    @property
    def byte_order(self) -> str:
        """numpy's byte-order prefix of the body (``"<"`` or ``">"``; ``""`` for ASCII)."""
        return _FORMATS[self.encoding]

    @property
    def faces(self) -> int:
        """Faces the header declares (0 without a ``face`` element): more than 0 is a mesh."""
        return sum(e.count for e in self.elements if e.name == "face")

    @property
    def meta(self) -> dict[str, list[str]]:
        """What :attr:`Scan.meta` gets from the header: its ``comment`` and ``obj_info`` lines
        (the text after the keyword), which may say which app or scanner wrote the file."""
        return {"comments": list(self.comments)}


def _parse_property(words: list[str], where: str) -> PlyProperty:
    """Build the property declared by one ``property`` header line (scalar or list)."""
    if len(words) == 3 and words[1] in PLY_TYPES:
        return PlyProperty(words[2], PLY_TYPES[words[1]])
    if len(words) == 5 and words[1] == "list" and words[2] in PLY_TYPES and words[3] in PLY_TYPES:
        return PlyProperty(words[4], PLY_TYPES[words[3]], PLY_TYPES[words[2]])
    raise ScanFormatError(
        f"{where}: expected 'property <type> <name>' or 'property list <type> <type> "
        f"<name>' with types among {sorted(set(PLY_TYPES))}"
    )


def _check_vertex(header: PlyHeader, path: Path) -> None:
    """Require a fixed-size vertex element with x/y/z properties, the minimum a scan needs."""
    vertex = vertex_element(header, path)
    names = [p.name for p in vertex.properties]
    missing = [a for a in "xyz" if pick_name(names, (a,)) is None]
    if missing:
        raise ScanFormatError(
            f"{path}: PLY vertex element has no {'/'.join(missing)} property "
            f"(properties: {' '.join(names) or 'none'})"
        )
    if not vertex.fixed_size:
        raise ScanFormatError(f"{path}: PLY vertex element has list properties; not supported")


def parse_header(buf: bytes, path: Path) -> PlyHeader:
    """Parse and check a PLY header.

    Parameters
    ----------
    buf : bytes
        The start of the file (at least the whole header).
    path : Path
        The file, for messages.

    Returns
    -------
    PlyHeader

    Raises
    ------
    ScanFormatError
        On a missing ``ply`` magic line or ``end_header``, an unknown format, type or keyword, a
        duplicate property, or a missing vertex element or x/y/z property.
    """
    if buf[:3] != b"ply" or buf[3:4] not in (b"\n", b"\r"):
        raise ScanFormatError(
            f"{path}: not a PLY file (it does not start with the 'ply' magic line)"
        )
    end = buf.find(b"end_header", 0, _MAX_HEADER_BYTES)
    if end < 0:
        raise ScanFormatError(f"{path}: PLY header has no 'end_header' line (truncated file?)")
    nl = buf.find(b"\n", end)
    if nl < 0:
        raise ScanFormatError(f"{path}: PLY file ends right after 'end_header' with no body")
    try:
        text = buf[:end].decode("ascii")
    except UnicodeDecodeError as exc:
        raise ScanFormatError(f"{path}: PLY header contains non-ASCII bytes") from exc
    encoding = None
    elements: list[PlyElement] = []
    comments: list[str] = []
    lines = text.replace("\r", "").split("\n")
    for i, line in enumerate(lines[1:], start=2):
        words = line.split()
        if words and words[0] in ("comment", "obj_info"):
            comments.append(line.strip()[len(words[0]) :].strip())
        if not words or words[0] in ("comment", "obj_info"):
            continue
        where = f"{path}: PLY header line {i} ({line.strip()[:60]!r})"
        key = words[0]
        if key == "format":
            if len(words) != 3 or words[1] not in _FORMATS:
                raise ScanFormatError(
                    f"{where}: expected 'format ascii|binary_little_endian|binary_big_endian 1.0'"
                )
            encoding = words[1]
        elif key == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise ScanFormatError(f"{where}: expected 'element <name> <count>'")
            elements.append(PlyElement(words[1], int(words[2]), i))
        elif key == "property":
            if not elements:
                raise ScanFormatError(f"{where}: property before any element")
            props = elements[-1].properties
            prop = _parse_property(words, where)
            if any(p.name == prop.name for p in props):
                raise ScanFormatError(f"{where}: property {prop.name!r} is declared twice")
            props.append(prop)
        else:
            raise ScanFormatError(f"{where}: unknown header keyword {key!r}")
    if encoding is None:
        raise ScanFormatError(f"{path}: PLY header has no 'format' line")
    header = PlyHeader(encoding, elements, nl + 1, len(lines), comments)
    _check_vertex(header, path)
    return header


def vertex_element(header: PlyHeader, path: Path) -> PlyElement:
    """Return the ``vertex`` element or raise a ScanFormatError naming the elements present."""
    for element in header.elements:
        if element.name == "vertex":
            return element
    found = ", ".join(e.name for e in header.elements) or "none"
    raise ScanFormatError(f"{path}: PLY file has no 'vertex' element (elements: {found})")


def vertex_offset(header: PlyHeader, path: Path) -> int | None:
    """Byte offset of a binary PLY's vertex records; None when a list element before them hides it.

    Raises
    ------
    ScanFormatError
        When the header has no vertex element.
    """
    offset = header.body_offset
    vertex = vertex_element(header, path)
    for element in header.elements:
        if element is vertex:
            break
        if not element.fixed_size:
            return None
        offset += element.count * element.dtype(header.byte_order).itemsize
    return offset


def binary_vertex_block(path: Path, header: PlyHeader) -> tuple[int, np.dtype] | None:
    """Where the vertices of a binary PLY start and their record dtype, checked against the size.

    Returns
    -------
    tuple of (int, numpy.dtype) or None
        Byte offset and structured dtype (in the file's byte order); None when an element with
        list properties comes before the vertices, so their offset is unknown without parsing.

    Raises
    ------
    ScanFormatError
        When the file is shorter or longer than the header's counts need.
    """
    offset = vertex_offset(header, path)
    if offset is None:
        return None
    _check_binary_size(path, header, os.path.getsize(path), offset)
    return offset, vertex_element(header, path).dtype(header.byte_order)


def _read_binary(path: Path, header: PlyHeader) -> np.ndarray:
    block = binary_vertex_block(path, header)
    if block is None:
        return _read_with_plyfile(path)
    offset, dtype = block
    vertex = vertex_element(header, path)
    with open(path, "rb") as fh:
        fh.seek(offset)
        data = np.fromfile(fh, dtype=dtype, count=vertex.count)
    if data.shape[0] != vertex.count:  # the file shrank between the size check and the read
        raise ScanFormatError(
            f"{path}: truncated PLY: read {data.shape[0]:,} of {vertex.count:,} vertices"
        )
    return data


def _check_binary_size(path: Path, header: PlyHeader, size: int, vertex_offset: int) -> None:
    """Compare the file size with the header's counts (truncated or extra body)."""
    order = _FORMATS[header.encoding]
    vertex = vertex_element(header, path)
    itemsize = vertex.dtype(order).itemsize
    have = size - vertex_offset
    need = vertex.count * itemsize
    if have < need:
        raise ScanFormatError(
            f"{path}: truncated PLY: the header declares {vertex.count:,} vertices "
            f"({need:,} bytes) but only {max(have, 0):,} bytes follow "
            f"({max(have, 0) // itemsize:,} complete vertices)"
        )
    if all(e.fixed_size for e in header.elements):
        expected = header.body_offset + sum(
            e.count * e.dtype(order).itemsize for e in header.elements
        )
        extra = size - expected
        if extra < 0:
            raise ScanFormatError(
                f"{path}: truncated PLY: the header's elements need {expected:,} bytes but the "
                f"file has {size:,}"
            )
        if extra >= itemsize:
            raise ScanFormatError(
                f"{path}: the PLY body is {extra:,} bytes longer than the header declares "
                f"({vertex.count:,} vertices); the header's vertex count is wrong "
                f"(about {extra // itemsize:,} more vertices in the file)"
            )


def _read_with_plyfile(path: Path) -> np.ndarray:
    """Fallback for binary files with list elements before the vertices (rare)."""
    import plyfile

    try:
        ply = plyfile.PlyData.read(str(path))
        return np.asarray(ply["vertex"].data)
    except (plyfile.PlyParseError, ValueError, KeyError, OSError) as exc:
        raise ScanFormatError(f"{path}: could not read PLY body: {library_reason(exc)}") from exc


def _ascii_body(path: Path, header: PlyHeader) -> tuple[bytes, np.ndarray]:
    """Read an ASCII body and check its line count against the header's element counts."""
    vertex = vertex_element(header, path)
    before = sum(e.count for e in header.elements[: header.elements.index(vertex)])
    body = path.read_bytes()[header.body_offset :].rstrip()  # trailing blank lines are fine
    newlines = np.flatnonzero(np.frombuffer(body, dtype=np.uint8) == 10)
    n_lines = newlines.size + 1 if body else 0
    declared = sum(e.count for e in header.elements)
    first_line = header.n_lines + 1
    if n_lines < before + vertex.count:
        raise ScanFormatError(
            f"{path}: the PLY header declares {vertex.count:,} vertices but the file has only "
            f"{max(0, n_lines - before):,} vertex lines (truncated, or the count is wrong)"
        )
    if n_lines > declared:
        raise ScanFormatError(
            f"{path}: the PLY file has {n_lines - declared:,} more lines than the header "
            f"declares ("
            f"{', '.join(f'{e.count:,} {e.name}' for e in header.elements)}); "
            f"the header's counts are wrong (first extra line: {first_line + declared})"
        )
    return body, newlines


def _read_ascii(
    path: Path, header: PlyHeader, progress: ProgressFn | None
) -> tuple[np.ndarray, int]:
    vertex = vertex_element(header, path)
    before = sum(e.count for e in header.elements[: header.elements.index(vertex)])
    first_line = header.n_lines + 1
    body, newlines = _ascii_body(path, header)
    start = int(newlines[before - 1]) + 1 if before else 0
    last = before + vertex.count - 1
    stop = int(newlines[last]) + 1 if last < newlines.size else len(body)
    values, _ = parse_table(
        body,
        path=path,
        start=start,
        stop=stop,
        first_line=first_line + before,
        ncols=len(vertex.properties),
        progress=progress,
    )
    if values.shape[0] != vertex.count:
        raise ScanFormatError(
            f"{path}: the PLY header declares {vertex.count:,} vertices but "
            f"{values.shape[0]:,} non-blank vertex lines were found"
        )
    out = np.empty(vertex.count, dtype=vertex.dtype("="))
    for i, prop in enumerate(vertex.properties):
        col = values[:, i]
        if prop.dtype[0] in "iu":
            info = np.iinfo(prop.dtype)
            bad = (col != np.rint(col)) | (col < info.min) | (col > info.max)
            if bad.any():
                j = int(np.flatnonzero(bad)[0])
                raise ScanFormatError(
                    f"{path}: line {first_line + before + j}: value {col[j]} of property "
                    f"{prop.name!r} is not a valid {prop.dtype} integer"
                )
        out[prop.name] = col
    return out, first_line + before


def probe_header(path: Path) -> PlyHeader:
    """Read and parse the header at the start of ``path``."""
    with open(path, "rb") as fh:
        head = fh.read(_MAX_HEADER_BYTES)
    return parse_header(head, path)


@dataclass(frozen=True)
class VertexFacts:
    """What the whole vertex element says that changes how each vertex is read.

    :func:`read_ply` decides from all vertices at once how colour is encoded (8-bit, 16-bit,
    0-1 floats) and whether raw label values are kept as a field. A reader that goes chunk by
    chunk gathers these facts in a first pass (:func:`vertex_facts` per chunk, :meth:`merge`).

    Attributes
    ----------
    colour : tuple of (float, float) or None
        Smallest and largest colour value; None when there is no colour or it is uint8.
    labels : LabelSummary or None
        Label values that are no S3DIS class; None without a label property.
    """

    colour: ColourRange | None = None
    labels: LabelSummary | None = None

    def merge(self, other: VertexFacts) -> VertexFacts:
        """The facts of two consecutive chunks together."""
        labels = other.labels
        if self.labels is not None:
            labels = self.labels if other.labels is None else self.labels.merge(other.labels)
        return VertexFacts(merge_colour_ranges(self.colour, other.colour), labels)


def vertex_columns(names: list[str]) -> tuple[tuple[str, str, str] | None, str | None]:
    """The colour properties and the label property among a vertex element's ``names``."""
    return pick_colour_names(names), pick_name(names, LABEL_NAMES)


def _colour_what(colour: tuple[str, str, str]) -> str:
    return "colour " + "/".join(colour)


def vertex_facts(data: np.ndarray, path: Path, *, start: int = 0) -> VertexFacts:
    """The :class:`VertexFacts` of ``data`` (all vertices, or one chunk starting at ``start``).

    Raises
    ------
    ScanFormatError
        On non-finite colour or labels that are not whole numbers (naming the vertex).
    """
    colour, label = vertex_columns(list(data.dtype.names or ()))
    rng = None
    if colour is not None:
        channels = np.stack([data[c] for c in colour], axis=1)
        rng = colour_range(channels, path=path, what=_colour_what(colour), start=start)
    labels = None
    if label is not None:
        labels = label_summary(data[label], path=path, source=label, start=start)
    return VertexFacts(rng, labels)


def split_vertex(
    data: np.ndarray,
    path: Path,
    facts: VertexFacts | None = None,
    *,
    start: int = 0,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None, dict[str, np.ndarray]]:
    """Split vertex records into xyz, rgb, labels and fields, as :func:`read_ply` returns them.

    Parameters
    ----------
    data : structured ndarray
        Vertex records: all of them, or one chunk.
    path : Path
        The file, for messages.
    facts : VertexFacts, optional
        The whole element's facts when ``data`` is one chunk (the caller has logged the
        warnings); by default ``data`` is the whole element.
    start : int
        Index of the first vertex of ``data`` in the file, for messages.

    Returns
    -------
    xyz, rgb, labels, fields
        New arrays (no views of ``data``, except a raw label field).
    """
    names = list(data.dtype.names or ())
    axes = [pick_name(names, (a,)) for a in "xyz"]
    xyz = np.empty((data.shape[0], 3), dtype=np.float64)
    for i, axis in enumerate(axes):
        xyz[:, i] = data[axis]
    used = set(axes)
    rgb = None
    colour, label_name = vertex_columns(names)
    if colour is not None:
        used.update(colour)
        rgb = to_rgb8(
            np.stack([data[c] for c in colour], axis=1),
            path=path,
            what=_colour_what(colour),
            value_range=None if facts is None else facts.colour,
        )
    labels = None
    fields: dict[str, np.ndarray] = {}
    if label_name is not None:
        used.add(label_name)
        labels, fields = normalise_labels(
            data[label_name],
            path=path,
            source=label_name,
            summary=None if facts is None else facts.labels,
            start=start,
        )
    for name in names:
        if name not in used:
            col = data[name]
            fields[name] = col.astype(col.dtype.newbyteorder("="))
    return xyz, rgb, labels, fields


def read_ply(path: Path, *, max_points: int, progress: ProgressFn | None = None) -> Scan:
    """Read the vertices of a PLY file.

    Parameters
    ----------
    path : Path
    max_points : int
        Refuse files whose header declares more vertices (checked before the body is read).
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    Scan
        ``meta["comments"]`` holds the header's comments. The vertices only: a PLY with faces
        is read as a mesh by :func:`jointseg.io.formats.read_ply_file`, which
        :func:`jointseg.io.read_scan` calls.

    Raises
    ------
    ScanFormatError
        On a bad header, a body shorter or longer than declared, unparsable ASCII lines,
        non-finite coordinates or too many vertices.
    """
    header = probe_header(path)
    vertex = vertex_element(header, path)
    check_max_points(vertex.count, max_points, path)
    report(progress, "read", 0.0)
    first_line = 0
    if header.encoding == "ascii":
        data, first_line = _read_ascii(path, header, progress)
    else:
        data = _read_binary(path, header)
    xyz, rgb, labels, fields = split_vertex(data, path)
    report(progress, "read", 1.0)
    if first_line:
        scan = build_scan(
            path, "ply", xyz, rgb, labels, fields, locate=lambda i: f"line {first_line + i}"
        )
    else:
        scan = build_scan(path, "ply", xyz, rgb, labels, fields)
    return replace(scan, meta=header.meta)


def probe_ply(path: Path, *, max_points: int) -> ScanInfo:
    """Check a PLY header and body size and report what it declares.

    Parameters
    ----------
    path : Path
    max_points : int

    Returns
    -------
    ScanInfo
        Of the vertices (:func:`jointseg.io.formats.probe_ply_file` probes a mesh).

    Raises
    ------
    ScanFormatError
        On a bad header, too many vertices, or (binary) a body shorter or longer than declared.
    """
    header = probe_header(path)
    vertex = vertex_element(header, path)
    check_max_points(vertex.count, max_points, path)
    if header.encoding == "ascii":
        _ascii_body(path, header)
    else:
        offset = vertex_offset(header, path)
        if offset is not None:
            _check_binary_size(path, header, os.path.getsize(path), offset)
    names = [p.name for p in vertex.properties]
    colour = pick_colour_names(names)
    label = pick_name(names, LABEL_NAMES)
    used = {pick_name(names, (a,)) for a in "xyz"} | set(colour or ()) | {label}
    return ScanInfo(
        path=str(path),
        format="ply",
        n_points=vertex.count,
        has_rgb=colour is not None,
        has_labels=label is not None,
        fields=tuple(n for n in names if n not in used),
    )


def _vertex_columns(
    scan: Scan, path: Path, fields: tuple[FieldColumn, ...], dtype: np.dtype | None = None
) -> dict[str, np.ndarray]:
    """The vertex properties of ``scan`` in writing order: xyz, colour, label, field columns.

    Field columns are narrowed to what PLY stores (:func:`narrow_dtype`), or to the property
    types of ``dtype`` when the header was made from a sample (:func:`narrow_like`).
    """
    columns: dict[str, np.ndarray] = {"x": scan.xyz[:, 0], "y": scan.xyz[:, 1], "z": scan.xyz[:, 2]}
    if scan.rgb is not None:
        columns.update(red=scan.rgb[:, 0], green=scan.rgb[:, 1], blue=scan.rgb[:, 2])
    if scan.labels is not None:
        columns["label"] = scan.labels
    for col in fields:
        if col.name in columns:
            raise ScanFormatError(f"{path}: field {col.name!r} clashes with a PLY vertex property")
        values = col.take(scan.fields)
        if dtype is None:
            columns[col.name] = narrow_dtype(values, name=col.name, path=path)
        else:
            columns[col.name] = narrow_like(values, dtype[col.name], name=col.name, path=path)
    return columns


@dataclass(frozen=True)
class PlyLayout:
    """The vertex properties :func:`write_ply` gives a scan, fixed once per file.

    So :func:`write_ply` and a writer that goes chunk by chunk write the same header and
    records.

    Attributes
    ----------
    fields : tuple of FieldColumn
        The scan's fields as scalar properties.
    dtype : numpy.dtype
        The little-endian vertex record.
    """

    fields: tuple[FieldColumn, ...]
    dtype: np.dtype

    def header(self, count: int) -> bytes:
        """The PLY header for ``count`` vertices."""
        lines = [
            "ply",
            "format binary_little_endian 1.0",
            "comment written by jointseg",
            f"element vertex {count}",
        ]
        assert self.dtype.names is not None
        lines += [
            f"property {_WRITE_TYPES[self.dtype[name].str[1:]]} {name}" for name in self.dtype.names
        ]
        lines.append("end_header\n")
        return "\n".join(lines).encode("ascii")

    def write(self, fh: BinaryIO, scan: Scan, path: Path) -> None:
        """Write the vertex records of ``scan`` (one chunk of the scan the layout was made
        for) to ``fh``.

        Raises
        ------
        ScanFormatError
            When a 64-bit integer field holds values the chosen property type cannot.
        """
        _write_records(fh, self.dtype, _vertex_columns(scan, path, self.fields, self.dtype), None)


#: Vertices filled and written at a time: a block of records that stays in the CPU's cache
#: while each field is copied in (the whole record array filled field by field streams it
#: through memory once per field: 0.39 s against 0.09 s for 1 M 60-byte vertices).
WRITE_BLOCK = 1 << 15


def _write_records(
    fh: BinaryIO, dtype: np.dtype, columns: dict[str, np.ndarray], progress: ProgressFn | None
) -> None:
    """Write the vertex records of ``columns`` to ``fh``, a block at a time."""
    n = len(next(iter(columns.values())))
    block = np.empty(min(n, WRITE_BLOCK), dtype=dtype)
    for start in range(0, n, WRITE_BLOCK):
        stop = min(start + WRITE_BLOCK, n)
        part = block[: stop - start]
        for name, col in columns.items():
            part[name] = col[start:stop]
        fh.write(part.view(np.uint8).data)
        if stop < n:
            report(progress, "write", stop / n)


def _layout(columns: dict[str, np.ndarray], fields: list[FieldColumn]) -> PlyLayout:
    dtype = np.dtype([(name, "<" + col.dtype.str[1:]) for name, col in columns.items()])
    return PlyLayout(tuple(fields), dtype)


def ply_layout(like: Scan, path: Path) -> PlyLayout:
    """The :class:`PlyLayout` :func:`write_ply` would use for ``like``.

    Parameters
    ----------
    like : Scan
        The scan, or a sample with the same fields and dtypes (64-bit integer fields are
        narrowed by the sample's values).
    path : Path
        Target file, for messages.

    Raises
    ------
    ScanFormatError
        On a field that PLY cannot store (name or dtype).
    """
    fields = field_columns(like.fields, path=path)
    return _layout(_vertex_columns(like, path, tuple(fields)), fields)


def write_ply(scan: Scan, path: Path, *, progress: ProgressFn | None = None) -> None:
    """Write a binary little-endian PLY keeping colour, labels and every field.

    Parameters
    ----------
    scan : Scan
    path : Path
        Target file (written atomically).
    progress : ProgressFn, optional
        Receives ``("write", fraction)``.

    Raises
    ------
    ScanFormatError
        On a field that PLY cannot store (name or dtype).
    """
    fields = field_columns(scan.fields, path=path)
    columns = _vertex_columns(scan, path, tuple(fields))
    layout = _layout(columns, fields)
    report(progress, "write", 0.0)
    with atomic_open(path) as fh:
        fh.write(layout.header(len(scan)))
        _write_records(fh, layout.dtype, columns, progress)
    report(progress, "write", 1.0)
