"""PCL's PCD format (v0.7): ``DATA ascii``, ``binary`` and ``binary_compressed`` (LZF).

Reading: the header (FIELDS SIZE TYPE COUNT WIDTH HEIGHT VIEWPOINT POINTS DATA) is parsed here.
Packed ``rgb`` / ``rgba`` (float32 or uint32 bits, 0x00RRGGBB) become the colour, a ``label``
field the labels, every other field (``normal_x``, ``curvature``, ``intensity``...) a field of
the same name and dtype; fields with COUNT > 1 become 2-D fields and ``_`` padding fields are
skipped. VIEWPOINT is not applied; it and an organised cloud's WIDTH x HEIGHT are kept in
``scan.meta`` for the frame stage (a depth camera's frame). In organised clouds (HEIGHT > 1)
points with NaN coordinates mark missing pixels and are dropped (logged); in unorganised
clouds a NaN coordinate is an error.

Writing: ``DATA binary`` with ``x y z`` as double (F 8), ``rgb`` packed in a float32, ``label``
as int32 (I 4) and every field with its own type; a 2-D field keeps its width as COUNT.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from jointseg.exceptions import ScanFormatError, library_reason
from jointseg.io.atomic import atomic_open
from jointseg.io.build import build_scan
from jointseg.io.colour import to_rgb8
from jointseg.io.columns import LABEL_NAMES, pick_colour_names, pick_name
from jointseg.io.fields import narrow_dtype, safe_field_name
from jointseg.io.formats.pcd import lzf
from jointseg.io.labels import normalise_labels
from jointseg.io.limits import (
    DEFAULT_MAX_INFLATION,
    ScanInfo,
    check_inflation,
    check_max_points,
)
from jointseg.io.tabular import count_lines, parse_table
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

_MAX_HEADER_BYTES = 1 << 20
_TYPES = {
    ("I", 1): "i1",
    ("I", 2): "i2",
    ("I", 4): "i4",
    ("I", 8): "i8",
    ("U", 1): "u1",
    ("U", 2): "u2",
    ("U", 4): "u4",
    ("U", 8): "u8",
    ("F", 4): "f4",
    ("F", 8): "f8",
}
_DATA_KINDS = ("ascii", "binary", "binary_compressed")
_HEADER_KEYWORDS = (
    "VERSION",
    "FIELDS",
    "SIZE",
    "TYPE",
    "COUNT",
    "WIDTH",
    "HEIGHT",
    "VIEWPOINT",
    "POINTS",
    "DATA",
)
_PACKED_COLOUR = ("rgb", "rgba")


@dataclass
class PcdHeader:
    """The parsed PCD header."""

    fields: list[str]
    types: list[str]
    counts: list[int]
    width: int
    height: int
    points: int
    data: str
    body_offset: int
    n_lines: int
    viewpoint: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)

    def meta(self) -> dict[str, object]:
        """What the frame stage reads from the header: the sensor pose (VIEWPOINT: tx ty tz
        qw qx qy qz) and, for an organised cloud, the sensor's image size."""
        out: dict[str, object] = {"pcd_viewpoint": list(self.viewpoint)}
        if self.height > 1:
            out["organised"] = [self.width, self.height]
        return out

    def dtype(self) -> np.dtype:
        """Packed little-endian record dtype (padding fields get unique private names)."""
        spec = []
        for i, (name, typ, count) in enumerate(
            zip(self.fields, self.types, self.counts, strict=True)
        ):
            key = name if name != "_" else f"__pad{i}"
            spec.append((key, "<" + typ) if count == 1 else (key, "<" + typ, (count,)))
        return np.dtype(spec)


def parse_header(head: bytes, path: Path) -> PcdHeader:
    """Parse and check a PCD header.

    Parameters
    ----------
    head : bytes
        The start of the file (at least the whole header).
    path : Path
        The file, for messages.

    Returns
    -------
    PcdHeader

    Raises
    ------
    ScanFormatError
        On a missing or inconsistent entry, an unknown type or DATA kind, or missing x/y/z.
    """
    entries, body_offset, data_line = _header_entries(head, path)
    fields, sizes, counts, width, height, points = _header_layout(entries, path)
    types = _field_types(fields, entries["TYPE"], sizes, counts, path)
    if points != width * height:
        raise ScanFormatError(
            f"{path}: PCD header says POINTS {points} but WIDTH × HEIGHT = {width} × {height} = "
            f"{width * height}"
        )
    data = entries["DATA"][0].lower() if entries["DATA"] else ""
    if data not in _DATA_KINDS:
        raise ScanFormatError(
            f"{path}: PCD DATA {data!r} is not supported (expected ascii, binary or "
            f"binary_compressed)"
        )
    missing = [a for a in "xyz" if a not in fields or counts[fields.index(a)] != 1]
    if missing:
        raise ScanFormatError(
            f"{path}: PCD has no scalar {'/'.join(missing)} field (fields: {' '.join(fields)})"
        )
    view = _viewpoint(entries.get("VIEWPOINT"), path)
    return PcdHeader(
        fields, types, counts, width, height, points, data, body_offset, data_line, view
    )


def _viewpoint(words: list[str] | None, path: Path) -> tuple[float, ...]:
    """VIEWPOINT's seven numbers; the default (identity) when absent or malformed, which
    the format allows to be ignored (it is recorded for the frame stage, never applied)."""
    default = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    if not words:
        return default
    try:
        values = tuple(float(w) for w in words)
    except ValueError:
        values = ()
    if len(values) != 7 or not all(np.isfinite(values)):
        logger.warning("%s: PCD VIEWPOINT %r is malformed; ignored", path, " ".join(words))
        return default
    return values


def _header_entries(head: bytes, path: Path) -> tuple[dict[str, list[str]], int, int]:
    """The header's keyword lines up to DATA, so anything else at the top is refused early.

    Returns the values of each keyword, the byte offset of the body and the DATA line number.
    """
    entries: dict[str, list[str]] = {}
    pos, line_no = 0, 0
    while pos < len(head):
        nl = head.find(b"\n", pos)
        if nl < 0:
            break
        raw = head[pos:nl]
        pos, line_no = nl + 1, line_no + 1
        try:
            line = raw.decode("ascii").strip()
        except UnicodeDecodeError as exc:
            raise ScanFormatError(
                f"{path}: not a PCD file (line {line_no} of the header is not text)"
            ) from exc
        if not line or line.startswith("#"):
            continue
        word, *values = line.split()
        key = word.upper()
        if key not in _HEADER_KEYWORDS:
            raise ScanFormatError(
                f"{path}: not a PCD file or bad header: line {line_no} starts with {word!r}, "
                f"expected a PCD header keyword (VERSION, FIELDS, ..., DATA)"
            )
        entries[key] = values
        if key == "DATA":
            return entries, pos, line_no
    raise ScanFormatError(f"{path}: PCD header has no DATA line (not a PCD file, or truncated)")


def _header_layout(
    entries: dict[str, list[str]], path: Path
) -> tuple[list[str], list[int], list[int], int, int, int]:
    """Field names, sizes and counts, WIDTH, HEIGHT and POINTS, checked for presence,
    agreement in length and integer values: (fields, sizes, counts, width, height, points)."""
    for key in ("FIELDS", "SIZE", "TYPE", "WIDTH"):
        if key not in entries:
            raise ScanFormatError(f"{path}: PCD header has no {key} line")
    fields = entries["FIELDS"]
    n = len(fields)
    counts_raw = entries.get("COUNT", ["1"] * n)
    if not (len(entries["SIZE"]) == len(entries["TYPE"]) == len(counts_raw) == n):
        raise ScanFormatError(
            f"{path}: PCD header lists {n} FIELDS but {len(entries['SIZE'])} SIZE, "
            f"{len(entries['TYPE'])} TYPE and {len(counts_raw)} COUNT values"
        )
    try:
        sizes = [int(s) for s in entries["SIZE"]]
        counts = [int(c) for c in counts_raw]
        width = int(entries["WIDTH"][0])
        height = int(entries.get("HEIGHT", ["1"])[0])
        points = int(entries["POINTS"][0]) if "POINTS" in entries else width * height
    except (ValueError, IndexError) as exc:
        raise ScanFormatError(
            f"{path}: PCD header has a non-integer SIZE/COUNT/WIDTH/HEIGHT/POINTS value"
        ) from exc
    return fields, sizes, counts, width, height, points


def _field_types(
    fields: list[str], type_codes: list[str], sizes: list[int], counts: list[int], path: Path
) -> list[str]:
    """Numpy type code of every field (refusing types numpy cannot read and repeated names)."""
    types = []
    for name, typ, size, count in zip(fields, type_codes, sizes, counts, strict=True):
        code = _TYPES.get((typ.upper(), size))
        if code is None or count < 1:
            raise ScanFormatError(
                f"{path}: PCD field {name!r} has unsupported TYPE {typ} / SIZE {size} / COUNT "
                f"{count}"
            )
        types.append(code)
    named = [f for f in fields if f != "_"]
    if len(set(named)) != len(named):
        raise ScanFormatError(f"{path}: PCD header repeats a field name: {' '.join(fields)}")
    return types


def _scalar_fields(header: PcdHeader) -> list[str]:
    """Fields with COUNT 1 (only those can be colour channels or labels)."""
    return [n for n, c in zip(header.fields, header.counts, strict=True) if n != "_" and c == 1]


def _read_head(path: Path) -> PcdHeader:
    with open(path, "rb") as fh:
        head = fh.read(_MAX_HEADER_BYTES)
    return parse_header(head, path)


def _check_size(
    path: Path, header: PcdHeader, size: int, max_inflation: float = DEFAULT_MAX_INFLATION
) -> None:
    """The body against the header's POINTS before anything is allocated: exactly for binary,
    the LZF block against ``max_inflation`` (ASCII lines are counted as they are parsed)."""
    dtype = header.dtype()
    have = size - header.body_offset
    if header.data == "binary":
        need = header.points * dtype.itemsize
        if have < need:
            raise ScanFormatError(
                f"{path}: truncated PCD: the header declares {header.points:,} points "
                f"({need:,} bytes) but only {have:,} bytes follow "
                f"({have // dtype.itemsize:,} complete points)"
            )
        if have - need >= dtype.itemsize:
            raise ScanFormatError(
                f"{path}: the PCD body holds {have // dtype.itemsize:,} points but the header "
                f"declares {header.points:,}; the header's POINTS/WIDTH is wrong"
            )
    elif header.data == "binary_compressed":
        if have < 8:
            raise ScanFormatError(f"{path}: truncated PCD: no compressed-size fields after DATA")
        with open(path, "rb") as fh:
            fh.seek(header.body_offset)
            sizes = np.frombuffer(fh.read(8), dtype="<u4")
        compressed, uncompressed = int(sizes[0]), int(sizes[1])
        if have - 8 < compressed:
            raise ScanFormatError(
                f"{path}: truncated PCD: {compressed:,} compressed bytes declared but only "
                f"{have - 8:,} follow"
            )
        check_inflation(
            uncompressed,
            compressed,
            max_inflation,
            path,
            what=f"the PCD header's {header.points:,} points",
        )
        if uncompressed != header.points * dtype.itemsize:
            raise ScanFormatError(
                f"{path}: the PCD compressed block holds {uncompressed:,} bytes, but "
                f"{header.points:,} points of {dtype.itemsize} bytes need "
                f"{header.points * dtype.itemsize:,}; the header's POINTS/WIDTH is wrong"
            )


def _read_compressed(path: Path, header: PcdHeader) -> np.ndarray:
    dtype = header.dtype()
    with open(path, "rb") as fh:
        fh.seek(header.body_offset)
        compressed, uncompressed = (int(v) for v in np.frombuffer(fh.read(8), dtype="<u4"))
        stream = fh.read(compressed)
    try:
        raw = lzf.decompress(stream, uncompressed)
    except lzf.LZFError as exc:
        raise ScanFormatError(
            f"{path}: corrupt binary_compressed PCD data: {library_reason(exc)}"
        ) from exc
    out = np.empty(header.points, dtype=dtype)
    offset = 0
    for key in dtype.names or ():
        sub = dtype[key]
        nbytes = sub.itemsize * header.points
        flat = np.frombuffer(raw, dtype=sub.base, count=nbytes // sub.base.itemsize, offset=offset)
        out[key] = flat.reshape(out[key].shape)
        offset += nbytes
    return out


def _read_ascii(
    path: Path, header: PcdHeader, progress: ProgressFn | None
) -> tuple[np.ndarray, int]:
    body = path.read_bytes()
    ncols = sum(header.counts)

    def too_many(rows: int) -> ScanFormatError:
        total = count_lines(body, header.body_offset)
        return ScanFormatError(
            f"{path}: the PCD header declares {header.points:,} points but the file has more "
            f"data lines (about {max(rows, total):,}); the header's POINTS/WIDTH is wrong"
        )

    values, _ = parse_table(
        body,
        path=path,
        start=header.body_offset,
        first_line=header.n_lines + 1,
        ncols=ncols,
        limit=header.points,
        on_limit=too_many,
        progress=progress,
    )
    if values.shape[0] != header.points:
        raise ScanFormatError(
            f"{path}: the PCD header declares {header.points:,} points but the file has "
            f"{values.shape[0]:,} data lines (truncated, or the header's POINTS is wrong)"
        )
    dtype = header.dtype()
    out = np.empty(header.points, dtype=dtype)
    col = 0
    for key, count in zip(dtype.names or (), header.counts, strict=True):
        block = values[:, col : col + count]
        col += count
        out[key] = block[:, 0] if count == 1 else block
    return out, header.n_lines + 1


def _unpack_rgb(values: np.ndarray, kind: str) -> np.ndarray:
    bits = values.astype(np.float32).view(np.uint32) if kind == "f" else values.astype(np.uint32)
    rgb = np.empty((bits.shape[0], 3), dtype=np.uint8)
    rgb[:, 0] = (bits >> 16) & 0xFF
    rgb[:, 1] = (bits >> 8) & 0xFF
    rgb[:, 2] = bits & 0xFF
    return rgb


def read_pcd(
    path: Path,
    *,
    max_points: int,
    max_inflation: float = DEFAULT_MAX_INFLATION,
    progress: ProgressFn | None = None,
) -> Scan:
    """Read a PCD file.

    Parameters
    ----------
    path : Path
    max_points : int
        Refuse files whose header declares more points (checked before the body is read).
    max_inflation : float
        Refuse a compressed body that inflates to more than this many times its size.
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    Scan

    Raises
    ------
    ScanFormatError
        On a bad header, a body shorter or longer than declared, unparsable ASCII lines,
        corrupt compressed data, NaN coordinates in an unorganised cloud or too many points.
    """
    header = _read_head(path)
    check_max_points(header.points, max_points, path)
    _check_size(path, header, os.path.getsize(path), max_inflation)
    report(progress, "read", 0.0)
    rec, first_line = _read_records(path, header, progress)
    xyz = np.stack([rec[a].astype(np.float64) for a in "xyz"], axis=1)
    index = np.arange(len(rec))
    if header.height > 1:
        keep = _valid_pixels(xyz, header, path)
        if keep is not None:
            rec, xyz, index = rec[keep], xyz[keep], index[keep]
    rgb, labels, fields = _colour_labels_fields(rec, header, path)
    report(progress, "read", 1.0)

    def locate(i: int) -> str:
        if first_line:
            return f"line {first_line + int(index[i])}"
        return f"record {int(index[i])}"

    scan = build_scan(path, "pcd", xyz, rgb, labels, fields, locate=locate)
    return replace(scan, meta={**scan.meta, **header.meta()})


def _read_records(
    path: Path, header: PcdHeader, progress: ProgressFn | None
) -> tuple[np.ndarray, int]:
    """The body as records of the header's dtype, whatever the DATA kind, and the file line of
    the first record (0 for binary bodies, whose records have no line)."""
    if header.data == "binary":
        with open(path, "rb") as fh:
            fh.seek(header.body_offset)
            rec = np.fromfile(fh, dtype=header.dtype(), count=header.points)
        if rec.shape[0] != header.points:
            raise ScanFormatError(
                f"{path}: truncated PCD: read {rec.shape[0]:,} of {header.points:,} points"
            )
        return rec, 0
    if header.data == "binary_compressed":
        return _read_compressed(path, header), 0
    return _read_ascii(path, header, progress)


def _valid_pixels(xyz: np.ndarray, header: PcdHeader, path: Path) -> np.ndarray | None:
    """Mask of the points of an organised cloud that are not missing pixels (NaN), None when
    none is missing: missing pixels are dropped, not an error."""
    nan = np.isnan(xyz).any(axis=1)
    if not nan.any():
        return None
    logger.info(
        "%s: dropped %d invalid (NaN) points of the organised %d×%d cloud",
        path,
        int(nan.sum()),
        header.width,
        header.height,
    )
    return ~nan


def _colour_labels_fields(
    rec: np.ndarray, header: PcdHeader, path: Path
) -> tuple[np.ndarray | None, np.ndarray | None, dict[str, np.ndarray]]:
    """Colour (packed or per channel), labels and every other field of the records, so each
    PCD field lands in exactly one place of the scan."""
    scalar = _scalar_fields(header)
    kinds = dict(zip(header.fields, header.types, strict=True))
    used = {"x", "y", "z"}
    rgb = None
    packed = next((n for n in scalar if n.lower() in _PACKED_COLOUR and kinds[n][1] == "4"), None)
    colour = pick_colour_names(scalar)
    if packed is not None:
        used.add(packed)
        rgb = _unpack_rgb(rec[packed], kinds[packed][0])
    elif colour is not None:
        used.update(colour)
        rgb = to_rgb8(np.stack([rec[c] for c in colour], axis=1), path=path)
    labels = None
    fields: dict[str, np.ndarray] = {}
    label_name = pick_name(scalar, LABEL_NAMES)
    if label_name is not None:
        used.add(label_name)
        labels, fields = normalise_labels(rec[label_name], path=path, source=label_name)
    for name in header.fields:
        if name != "_" and name not in used:
            fields[name] = np.ascontiguousarray(rec[name])
    return rgb, labels, fields


def probe_pcd(
    path: Path, *, max_points: int, max_inflation: float = DEFAULT_MAX_INFLATION
) -> ScanInfo:
    """Check a PCD header and its body size (binary) or line count (ASCII).

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
        On a bad header, too many points, or a body that does not match the header.
    """
    header = _read_head(path)
    check_max_points(header.points, max_points, path)
    _check_size(path, header, os.path.getsize(path), max_inflation)
    if header.data == "ascii":
        body = path.read_bytes()[header.body_offset :].rstrip()
        lines = count_lines(body) if body else 0
        if lines != header.points:
            raise ScanFormatError(
                f"{path}: the PCD header declares {header.points:,} points but the file has "
                f"{lines:,} data lines"
            )
    names = [n for n in header.fields if n != "_"]
    scalar = _scalar_fields(header)
    packed = any(n.lower() in _PACKED_COLOUR for n in scalar)
    colour = pick_colour_names(scalar)
    label = pick_name(scalar, LABEL_NAMES)
    used = {"x", "y", "z", label} | {n for n in scalar if n.lower() in _PACKED_COLOUR}
    used |= set(colour or ())
    return ScanInfo(
        path=str(path),
        format="pcd",
        n_points=header.points,
        has_rgb=packed or colour is not None,
        has_labels=label is not None,
        fields=tuple(n for n in names if n not in used),
    )


def write_pcd(scan: Scan, path: Path, *, progress: ProgressFn | None = None) -> None:
    """Write a binary PCD (x y z double, packed rgb, int32 label, fields with their types).

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
        On a field name or dtype PCD cannot store.
    """
    columns = _pcd_columns(scan, path)
    spec, sizes, types, counts = [], [], [], []
    for name, col in columns.items():
        base = col.dtype.newbyteorder("<")
        spec.append((name, base) if col.ndim == 1 else (name, base, (col.shape[1],)))
        sizes.append(str(base.itemsize))
        types.append({"i": "I", "u": "U", "f": "F"}[base.kind])
        counts.append(str(1 if col.ndim == 1 else col.shape[1]))
    record = np.empty(len(scan), dtype=np.dtype(spec))
    for name, col in columns.items():
        record[name] = col
    lines = [
        "# .PCD v0.7 - Point Cloud Data file format (written by jointseg)",
        "VERSION 0.7",
        "FIELDS " + " ".join(columns),
        "SIZE " + " ".join(sizes),
        "TYPE " + " ".join(types),
        "COUNT " + " ".join(counts),
        f"WIDTH {len(scan)}",
        "HEIGHT 1",
        "VIEWPOINT 0 0 0 1 0 0 0",
        f"POINTS {len(scan)}",
        "DATA binary",
        "",
    ]
    report(progress, "write", 0.0)
    with atomic_open(path) as fh:
        fh.write("\n".join(lines).encode("ascii"))
        fh.write(record.tobytes())
    report(progress, "write", 1.0)


def _pcd_columns(scan: Scan, path: Path) -> dict[str, np.ndarray]:
    """The columns PCD stores, by field name: x y z, packed rgb, label and the scan's fields
    narrowed to a type PCD has (refusing names that clash)."""
    columns: dict[str, np.ndarray] = {"x": scan.xyz[:, 0], "y": scan.xyz[:, 1], "z": scan.xyz[:, 2]}
    if scan.rgb is not None:
        rgb = scan.rgb.astype(np.uint32)
        columns["rgb"] = ((rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]).view(np.float32)
    if scan.labels is not None:
        columns["label"] = scan.labels
    for raw_name, values in scan.fields.items():
        name = safe_field_name(raw_name, path=path)
        if name in columns or name == "_":
            raise ScanFormatError(
                f"{path}: field {raw_name!r} cannot be written to PCD: the name {name!r} is "
                f"taken; rename the field"
            )
        cols = values.reshape(len(values), -1)
        narrowed = [narrow_dtype(cols[:, i], name=name, path=path) for i in range(cols.shape[1])]
        common = np.result_type(*narrowed)
        columns[name] = (
            np.stack(narrowed, axis=1).astype(common) if values.ndim == 2 else (narrowed[0])
        )
    return columns
