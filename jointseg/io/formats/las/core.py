"""LAS / LAZ through laspy (LAZ with the lazrs backend).

Reading: coordinates with the header's scales and offsets applied; 16-bit colour divided by 257
(colour whose maximum is ≤ 255 is taken as 8-bit already; colour 0 everywhere means none);
classification becomes labels, with 255 meaning unlabelled and values above 12 read as
unlabelled too, the raw classification then also kept as field ``classification``. A
classification that is 0 everywhere in a file not written by jointseg means "never classified"
and gives no labels. ``intensity`` (unless 0 everywhere) and every extra-bytes dimension become
fields. In a result file (below) labels come from ``input_classification`` instead, and a
result's classification is never read as labels.

Writing: LAS 1.4, point format 7 (6 when the scan has no colour), scale 0.1 mm (coarser when the
extent needs it) with offsets at the minimum; colour × 257; labels in classification (-1 as 255)
and a small VLR saying so; every field as an extra-bytes dimension of its own dtype (a 2-D field
``f`` as ``f_0 .. f_{k-1}``). A field named ``intensity`` holding whole numbers in 0..65535 goes
into the standard intensity dimension; a field whose name is another standard dimension (or a
float intensity) is stored as ``extra_<name>``, which reads back as ``<name>`` from files written
by jointseg. A result (a scan with ``fused_label``) has the fused classes in classification
(64 + class, :mod:`jointseg.io.formats.las.result`) and what classification would hold otherwise in
the extra dimension ``input_classification``.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import laspy
import numpy as np

from jointseg.exceptions import ScanFormatError, library_reason
from jointseg.io.atomic import atomic_open
from jointseg.io.build import build_scan
from jointseg.io.colour import ColourRange, merge_colour_ranges, to_rgb8
from jointseg.io.fields import FieldColumn, field_columns
from jointseg.io.formats.las.result import (
    INPUT_CLASSIFICATION,
    RESULT_BASE,
    RESULT_FIELD,
    RESULT_VLR_RECORD_ID,
    check_full_byte,
    lookup_vlr,
    result_classification,
)
from jointseg.io.labels import LabelSummary, label_summary, log_outside_labels, normalise_labels
from jointseg.io.limits import (
    DEFAULT_MAX_INFLATION,
    ScanInfo,
    check_inflation,
    check_max_points,
)
from jointseg.io.units import unit_from_geokeys, unit_from_wkt
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

#: VLR marking files whose classification holds S3DIS labels (written by jointseg).
LABELS_VLR_USER_ID = "jointseg"
LABELS_VLR_RECORD_ID = 1
_BASE_SCALE = 1e-4
_INT32_SPAN = 2**31 - 2
LASPY_ERRORS = (laspy.errors.LaspyException, ValueError, OSError, EOFError, RuntimeError)
_EXTRA_KINDS = frozenset("iuf")


def open_reader(
    path: Path, selection: laspy.DecompressionSelection | None = None
) -> laspy.LasReader:
    """Open ``path`` with laspy, turning a bad signature or header into a ScanFormatError.

    ``selection`` names the dimensions to decompress (LAZ with point formats 6-10 only; laspy
    ignores it elsewhere); by default all.
    """
    if selection is None:
        selection = laspy.DecompressionSelection.all()
    try:
        return laspy.open(str(path), decompression_selection=selection)
    except LASPY_ERRORS as exc:
        with open(path, "rb") as fh:
            magic = fh.read(4)
        if magic != b"LASF":
            raise ScanFormatError(
                f"{path}: not a LAS/LAZ file (it does not start with the 'LASF' signature)"
            ) from exc
        raise ScanFormatError(f"{path}: cannot read the LAS header: {library_reason(exc)}") from exc


def check_body_size(
    path: Path, header: laspy.LasHeader, max_inflation: float = DEFAULT_MAX_INFLATION
) -> None:
    """Compare the byte size of the point block with the header's count before any point is
    allocated: exactly for LAS, against ``max_inflation`` for LAZ (whose size cannot be known
    without decompressing)."""
    record = header.point_format.size
    if header.are_points_compressed:
        check_inflation(
            header.point_count * record,
            os.path.getsize(path) - header.offset_to_point_data,
            max_inflation,
            path,
            what=f"the LAZ header's {header.point_count:,} points of {record} bytes",
        )
        return
    start = header.offset_to_point_data
    end = os.path.getsize(path)
    if header.number_of_evlrs and header.start_of_first_evlr:
        end = min(end, header.start_of_first_evlr)
    have = end - start
    need = header.point_count * record
    if have < need:
        raise ScanFormatError(
            f"{path}: truncated LAS: the header declares {header.point_count:,} points "
            f"({need:,} bytes) but only {max(have, 0):,} bytes of point data follow "
            f"({max(have, 0) // record:,} complete points)"
        )
    if have - need >= record:
        raise ScanFormatError(
            f"{path}: the LAS point block holds {have // record:,} points but the header "
            f"declares {header.point_count:,}; the header's point count is wrong"
        )


def _has_marker(header: laspy.LasHeader, record_id: int) -> bool:
    """Whether the header holds jointseg's VLR of that record id."""
    return any(
        getattr(v, "user_id", "") == LABELS_VLR_USER_ID
        and getattr(v, "record_id", None) == record_id
        for v in header.vlrs
    )


def _labels_vlr(header: laspy.LasHeader) -> bool:
    return _has_marker(header, LABELS_VLR_RECORD_ID)


def _result_vlr(header: laspy.LasHeader) -> bool:
    return _has_marker(header, RESULT_VLR_RECORD_ID)


def label_source(point_format: laspy.PointFormat) -> str:
    """Where labels are read from: ``input_classification`` in a result file that has it (its
    classification holds the result), else ``classification``."""
    if INPUT_CLASSIFICATION in point_format.extra_dimension_names:
        return INPUT_CLASSIFICATION
    return "classification"


def _written_by_jointseg(header: laspy.LasHeader) -> bool:
    return str(header.generating_software).strip("\x00 ").startswith("jointseg")


@dataclass(frozen=True)
class LasFacts:
    """What the whole file's points say that changes how each point is read.

    :func:`read_las` decides from all points at once whether there is colour (and whether it is
    8- or 16-bit), whether classification holds labels, whether raw classification values are
    kept, and whether intensity is a field. A reader that goes chunk by chunk gathers these facts
    in a first pass (:func:`las_facts` per chunk, :meth:`merge`) so its chunks match.

    Attributes
    ----------
    colour : tuple of (float, float) or None
        Smallest and largest red/green/blue value; None when the point format has no colour.
    classified : bool
        Some classification is not 0 (``input_classification`` in a result file that has it,
        see :func:`label_source`).
    labels : LabelSummary
        Classification values that are no S3DIS class (nor 255).
    intensity : bool
        Some intensity is not 0.
    """

    colour: ColourRange | None = None
    classified: bool = False
    labels: LabelSummary = field(default_factory=LabelSummary)
    intensity: bool = False

    def merge(self, other: LasFacts) -> LasFacts:
        """The facts of two consecutive chunks together."""
        return LasFacts(
            merge_colour_ranges(self.colour, other.colour),
            self.classified or other.classified,
            self.labels.merge(other.labels),
            self.intensity or other.intensity,
        )


_RGB = ("red", "green", "blue")


def las_facts(points: laspy.PackedPointRecord, path: Path) -> LasFacts:
    """The :class:`LasFacts` of ``points`` (all of a file, or one chunk of it)."""
    arr = points.array
    colour = None
    if set(_RGB) <= set(points.point_format.dimension_names) and len(points):
        colour = (
            min(int(arr[c].min()) for c in _RGB),
            max(int(arr[c].max()) for c in _RGB),
        )
    cls = np.asarray(points[label_source(points.point_format)])
    return LasFacts(
        colour=colour,
        classified=bool(cls.any()),
        labels=label_summary(cls, path=path, source="classification", unlabelled_values=(255,)),
        intensity=bool(np.asarray(arr["intensity"]).any()),
    )


def reads_labels(header: laspy.LasHeader, facts: LasFacts) -> bool:
    """Whether the label source (:func:`label_source`) becomes labels: a file marked by
    jointseg, or one classified; never the classification of a result file (the fused
    classes, not ground truth)."""
    source = label_source(header.point_format)
    if source == "classification" and _result_vlr(header):
        return False
    return _labels_vlr(header) or facts.classified


def log_facts(header: laspy.LasHeader, facts: LasFacts, path: Path) -> None:
    """Log, once per file, what reading its points tells (odd classification values, a
    result's classification not read as labels)."""
    source = label_source(header.point_format)
    if _result_vlr(header) or source == INPUT_CLASSIFICATION:
        logger.info(
            "%s: a jointseg result: its classification holds the fused classes (%d + class, "
            "also in fused_label); %s",
            path,
            RESULT_BASE,
            "labels are read from input_classification"
            if source == INPUT_CLASSIFICATION
            else "it keeps no input labels, so it is read unlabelled",
        )
    if reads_labels(header, facts):
        log_outside_labels(facts.labels, path=path, source=source, raw_field="classification")


def points_to_scan(
    points: laspy.PackedPointRecord,
    header: laspy.LasHeader,
    facts: LasFacts,
    path: Path,
    *,
    start: int | None = None,
    bare: bool = False,
) -> Scan:
    """Turn LAS point records into a :class:`Scan`, deciding as ``facts`` (the whole file's) say.

    Parameters
    ----------
    points : laspy.PackedPointRecord
        All of the file's points, or one chunk of them.
    header : laspy.LasHeader
        The file's header (scales, offsets, VLRs).
    facts : LasFacts
        The whole file's facts.
    path : Path
        The file, for messages.
    start : int, optional
        Index of the first point in the file when ``points`` is one chunk, for messages.
    bare : bool
        Coordinates and colour only, no labels or fields: records read without those layers
        (a LAZ's selective decompression, for a sample or a coordinates pass) serve.

    Returns
    -------
    Scan
    """
    arr = points.array
    xyz, rgb = _xyz_rgb(points, header, facts, path)
    fmt = "laz" if header.are_points_compressed else "las"
    if bare:
        return build_scan(path, fmt, xyz, rgb, None, {}, start=start)
    fields: dict[str, np.ndarray] = {}
    labels = None
    source = label_source(points.point_format)
    if reads_labels(header, facts):
        labels, fields = normalise_labels(
            np.asarray(points[source]),
            path=path,
            source=source,
            raw_field="classification",
            unlabelled_values=(255,),
            summary=facts.labels,
            start=start or 0,
        )
    if facts.intensity:
        fields["intensity"] = np.array(arr["intensity"])
    ours = _written_by_jointseg(header)
    for name in points.point_format.extra_dimension_names:
        if name == INPUT_CLASSIFICATION:
            continue  # the labels (and a raw classification field), as read from the input
        key = name
        if ours and name.startswith("extra_") and name[6:] not in fields:
            key = name[6:]  # undo the renaming done by write_las
        fields[key] = np.array(points[name])
    return build_scan(path, fmt, xyz, rgb, labels, fields, start=start)


def _xyz_rgb(
    points: laspy.PackedPointRecord, header: laspy.LasHeader, facts: LasFacts, path: Path
) -> tuple[np.ndarray, np.ndarray | None]:
    """The records' coordinates (float64, scaled and offset) and 8-bit colour as the whole
    file's ``facts`` decide (None when the file has none)."""
    arr = points.array
    scales, offsets = header.scales, header.offsets
    xyz = np.empty((len(points), 3), dtype=np.float64)
    for i, axis in enumerate("XYZ"):
        np.multiply(arr[axis], scales[i], out=xyz[:, i])
        xyz[:, i] += offsets[i]
    rgb = None
    if facts.colour is not None and facts.colour[1] > 0:  # colour 0 everywhere means none
        rgb = to_rgb8(np.stack([arr[c] for c in _RGB], axis=1), path=path, value_range=facts.colour)
    return xyz, rgb


def point_read_error(path: Path, header: laspy.LasHeader, exc: Exception) -> ScanFormatError:
    """The error for points laspy could not read or decompress."""
    what = "decompress the LAZ" if header.are_points_compressed else "read the LAS"
    return ScanFormatError(
        f"{path}: cannot {what} points (truncated or corrupt file?): {library_reason(exc)}"
    )


def short_read_error(path: Path, header: laspy.LasHeader, got: int) -> ScanFormatError:
    """The error for a file with fewer points than its header declares."""
    return ScanFormatError(
        f"{path}: truncated LAS: the header declares {header.point_count:,} points but "
        f"only {got:,} could be read"
    )


def read_las(
    path: Path,
    *,
    max_points: int,
    max_inflation: float = DEFAULT_MAX_INFLATION,
    progress: ProgressFn | None = None,
) -> Scan:
    """Read a LAS or LAZ file.

    Parameters
    ----------
    path : Path
    max_points : int
        Refuse files whose header declares more points (checked before the points are read).
    max_inflation : float
        Refuse a LAZ whose declared points take more than this many times its size.
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    Scan

    Raises
    ------
    ScanFormatError
        On a wrong signature, a point block shorter or longer than declared, a LAZ declaring
        more than ``max_inflation`` times its size, a corrupt LAZ stream, non-finite
        coordinates or too many points.
    """
    report(progress, "read", 0.0)
    with open_reader(path) as reader:
        header = reader.header
        check_max_points(header.point_count, max_points, path)
        check_body_size(path, header, max_inflation)
        try:
            points = reader.read_points(header.point_count)
        except LASPY_ERRORS as exc:
            raise point_read_error(path, header, exc) from exc
    if len(points) != header.point_count:
        raise short_read_error(path, header, len(points))
    report(progress, "read", 0.7)
    facts = las_facts(points, path)
    log_facts(header, facts, path)
    scan = points_to_scan(points, header, facts, path)
    report(progress, "read", 1.0)
    return replace(scan, meta=las_meta(header))


#: The VLR user id of a LAS file's coordinate reference system records.
PROJECTION_USER_ID = "LASF_Projection"
_WKT_RECORD, _GEOKEYS_RECORD = 2112, 34735


def las_meta(header: laspy.LasHeader) -> dict[str, Any]:
    """What a LAS header says about the whole scan: its CRS records, scales and offsets (an
    output keeps them) and the linear unit its CRS names (the frame stage reads it)."""
    records = [
        v
        for v in [*header.vlrs, *(getattr(header, "evlrs", None) or [])]
        if getattr(v, "user_id", "") == PROJECTION_USER_ID
    ]
    meta: dict[str, Any] = {
        "las": {
            "scales": np.asarray(header.scales, dtype=np.float64).copy(),
            "offsets": np.asarray(header.offsets, dtype=np.float64).copy(),
            "crs": [(v.record_id, v.description, bytes(v.record_data_bytes())) for v in records],
        }
    }
    for v in records:
        data = bytes(v.record_data_bytes())
        if v.record_id == _WKT_RECORD:
            unit = unit_from_wkt(data.decode("utf-8", "replace").rstrip("\x00"))
            how = "the file's CRS (OGC WKT)"
        elif v.record_id == _GEOKEYS_RECORD:
            unit = unit_from_geokeys(data)
            how = "the file's CRS (GeoTIFF keys)"
        else:
            continue
        if unit is not None:
            meta.update(units=unit, units_source=how)
            break
    return meta


def probe_las(
    path: Path, *, max_points: int, max_inflation: float = DEFAULT_MAX_INFLATION
) -> ScanInfo:
    """Check a LAS/LAZ header and the point block's size (exactly for LAS, against
    ``max_inflation`` for LAZ).

    Parameters
    ----------
    path : Path
    max_points : int
    max_inflation : float

    Returns
    -------
    ScanInfo
        For uncompressed files, ``has_rgb``, ``has_labels`` and an ``intensity`` field reflect
        what :func:`read_las` will return (the point block is memory-mapped, not parsed). LAZ
        points are not decompressed, so there they say what the point format can hold.

    Raises
    ------
    ScanFormatError
        On a wrong signature, a wrong point block size or too many points.
    """
    with open_reader(path) as reader:
        header = reader.header
    check_max_points(header.point_count, max_points, path)
    check_body_size(path, header, max_inflation)
    fmt = header.point_format
    dims = set(fmt.dimension_names)
    has_rgb = {"red", "green", "blue"} <= dims
    has_labels = has_intensity = True
    if not header.are_points_compressed and header.point_count:
        dtype = fmt.dtype()
        block = np.memmap(
            path,
            dtype=dtype,
            mode="r",
            offset=header.offset_to_point_data,
            shape=(header.point_count,),
        )
        source = label_source(fmt)
        if source in (dtype.names or ()):
            cls = block[source]
        else:
            cls = block["raw_classification"] & 0x1F
        has_labels = bool(cls.any())
        has_intensity = bool(block["intensity"].any())
        has_rgb = has_rgb and bool(
            block["red"].any() or block["green"].any() or block["blue"].any()
        )
        del block, cls
    has_labels = reads_labels(header, LasFacts(classified=has_labels))
    ours = _written_by_jointseg(header)
    extra = [
        n[6:] if ours and n.startswith("extra_") else n
        for n in fmt.extra_dimension_names
        if n != INPUT_CLASSIFICATION
    ]
    return ScanInfo(
        path=str(path),
        format="laz" if header.are_points_compressed else "las",
        n_points=header.point_count,
        has_rgb=has_rgb,
        has_labels=has_labels,
        fields=(("intensity",) if has_intensity else ()) + tuple(extra),
    )


def _extra_name(name: str, standard: set[str], path: Path) -> str:
    out = f"extra_{name}" if name.lower() in standard else name
    if out != name:
        logger.info(
            "%s: field %r does not fit LAS's standard dimension of that name; stored as extra "
            "bytes %r (read back as %r by jointseg)",
            path,
            name,
            out,
            name,
        )
    if len(out.encode()) > 32:
        raise ScanFormatError(
            f"{path}: field name {out!r} is longer than the 32 bytes LAS allows for extra bytes; "
            f"rename the field"
        )
    return out


def _fits_uint(values: np.ndarray, top: int) -> bool:
    if values.dtype.kind not in "iuf" or values.size == 0:
        return values.dtype.kind in "iu"
    if values.dtype.kind == "f" and not np.all(np.rint(values) == values):
        return False
    return bool(values.min() >= 0 and values.max() <= top)


def _extra_dtype(dtype: np.dtype, name: str, path: Path) -> np.dtype:
    """The little-endian dtype a field is stored with as LAS extra bytes."""
    if dtype.kind == "b":
        dtype = np.dtype(np.uint8)
    elif dtype.kind == "f" and dtype.itemsize == 2:
        dtype = np.dtype(np.float32)
    if dtype.kind not in _EXTRA_KINDS or dtype.itemsize > 8:
        raise ScanFormatError(
            f"{path}: field {name!r} has dtype {dtype}; LAS extra bytes hold only "
            f"integers and float32/float64"
        )
    return dtype.newbyteorder("<")


@dataclass(frozen=True)
class LasLayout:
    """How a scan's arrays go into LAS point records: the header and the choices behind it.

    Made once per file by :func:`las_layout`, so :func:`write_las` and a writer that goes chunk
    by chunk follow the same conventions.

    Attributes
    ----------
    header : laspy.LasHeader
        LAS 1.4, point format 7 (6 without colour), scales, offsets, extra bytes, labels VLR.
    scale : float
        The coordinate scale (the same on all axes).
    offsets : ndarray of shape (3,)
        The coordinate offsets: the scan's minimum.
    columns : tuple of FieldColumn
        The scan's fields as scalar columns.
    std_intensity : bool
        Column ``intensity`` goes into the standard intensity dimension.
    std_classification : bool
        Column ``classification`` goes into the standard classification (under the labels).
    extras : dict of str to tuple of (str, numpy.dtype)
        Every other column: its extra-bytes dimension name and dtype.
    result : bool
        The scan is a result (it has ``fused_label``): classification holds the fused classes
        (:mod:`jointseg.io.formats.las.result`).
    input_classification : bool
        In a result, what classification would hold otherwise (the labels, or a raw
        classification field) goes into the extra dimension ``input_classification``.
    """

    header: laspy.LasHeader
    scale: float
    offsets: np.ndarray
    columns: tuple[FieldColumn, ...]
    std_intensity: bool
    std_classification: bool
    extras: dict[str, tuple[str, np.dtype]]
    result: bool = False
    input_classification: bool = False


def las_layout(like: Scan, lo: np.ndarray, hi: np.ndarray, path: Path) -> LasLayout:
    """Build the header (and its conventions) for writing scans like ``like`` as LAS.

    Point format 7, or 6 when ``like`` has no colour; scale 0.1 mm, coarser by powers of ten
    while the extent ``hi - lo`` would overflow 32-bit integers; offsets at ``lo``; the labels
    VLR when ``like`` has labels; one extra-bytes dimension per field column. A field
    ``intensity`` (``classification``) goes into the standard dimension when ``like``'s values
    are whole numbers in 0..65535 (0..255). A result (``like`` has ``fused_label``) has its
    fused classes in classification, the input's in ``input_classification``, the result and
    Classification Lookup VLRs (:mod:`jointseg.io.formats.las.result`).

    Parameters
    ----------
    like : Scan
        The scan to write, or a sample with the same fields and dtypes (the standard-dimension
        choices then follow the sample's values).
    lo, hi : ndarray of shape (3,)
        Minimum and maximum coordinates of everything that will be written.
    path : Path
        Target file, for messages.

    Returns
    -------
    LasLayout

    Raises
    ------
    ScanFormatError
        On a field LAS cannot store (dtype or name too long), or a result with a field
        ``input_classification`` of its own beside labels.
    """
    header = laspy.LasHeader(point_format=7 if like.rgb is not None else 6, version="1.4")
    header.generating_software = "jointseg"
    standard = {d.lower() for d in header.point_format.dimension_names} | {"x", "y", "z"}
    scale = _BASE_SCALE
    while float((hi - lo).max()) / scale > _INT32_SPAN:
        scale *= 10.0
    header.scales = np.full(3, scale)
    header.offsets = lo
    scale, lo = _keep_input_grid(header, like.meta.get("las"), scale, lo, hi)
    columns = field_columns(like.fields, path=path)
    values = {col.name: col.take(like.fields) for col in columns}
    intensity = values.get("intensity")
    std_intensity = intensity is not None and _fits_uint(intensity, 65535)
    raw_cls = values.get("classification")
    std_cls = raw_cls is not None and _fits_uint(raw_cls, 255)
    extras: dict[str, tuple[str, np.dtype]] = {}
    for name, column in values.items():
        if (name == "intensity" and std_intensity) or (name == "classification" and std_cls):
            continue
        dtype = _extra_dtype(column.dtype, name, path)
        extras[name] = (_extra_name(name, standard, path), dtype)
    result = RESULT_FIELD in like.fields
    keep_input = result and (like.labels is not None or std_cls)
    dims = [laspy.ExtraBytesParams(name=dim, type=dtype) for dim, dtype in extras.values()]
    if keep_input:
        if INPUT_CLASSIFICATION in values:
            raise ScanFormatError(
                f"{path}: the scan has a field {INPUT_CLASSIFICATION!r} besides its labels or "
                f"classification, which a result LAS keeps under that name; rename the field"
            )
        dims.append(laspy.ExtraBytesParams(name=INPUT_CLASSIFICATION, type=np.dtype(np.uint8)))
    if dims:
        header.add_extra_dims(dims)
    header.vlrs.extend(_layout_vlrs(like, result, header.point_format.id, path))
    return LasLayout(
        header, scale, lo, tuple(columns), std_intensity, std_cls, extras, result, keep_input
    )


def _layout_vlrs(like: Scan, result: bool, point_format: int, path: Path) -> list[laspy.VLR]:
    """The labels VLR when ``like`` has labels (naming where they are); for a result, the
    jointseg result VLR and the Classification Lookup VLR."""

    def marker(record_id: int, description: str) -> laspy.VLR:  # descriptions: 32 bytes
        return laspy.VLR(LABELS_VLR_USER_ID, record_id, description, record_data=b"")

    out = []
    if like.labels is not None:
        where = f"{INPUT_CLASSIFICATION} = labels" if result else "classification = S3DIS labels"
        out.append(marker(LABELS_VLR_RECORD_ID, where))
    if result:
        check_full_byte(point_format, path)
        out.append(marker(RESULT_VLR_RECORD_ID, f"classification = {RESULT_BASE}+{RESULT_FIELD}"))
        out.append(lookup_vlr())
    return out


def _keep_input_grid(
    header: laspy.LasHeader,
    kept: dict[str, Any] | None,
    scale: float,
    lo: np.ndarray,
    hi: np.ndarray,
) -> tuple[float, np.ndarray]:
    """Give ``header`` a LAS input's own grid and origin (coordinates read from it write back
    unchanged) when the points fit them, and its CRS records; the scale and offsets used."""
    if kept is None:
        return scale, lo
    if np.ptp(kept["scales"]) == 0 and _fits(kept["scales"], kept["offsets"], lo, hi):
        header.scales = kept["scales"]
        header.offsets = kept["offsets"]
        scale, lo = float(np.max(kept["scales"])), kept["offsets"]
    for record_id, description, data in kept.get("crs", []):
        header.vlrs.append(
            laspy.VLR(
                user_id=PROJECTION_USER_ID,
                record_id=record_id,
                description=description,
                record_data=data,
            )
        )
    return scale, lo


def _fits(scales: np.ndarray, offsets: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether ``lo``..``hi`` is representable in 32-bit integers on that grid."""
    span = np.maximum(np.abs(lo - offsets), np.abs(hi - offsets)) / scales
    return bool(np.all(span < _INT32_SPAN))


def las_record(
    scan: Scan, layout: LasLayout, path: Path = Path("LAS")
) -> laspy.ScaleAwarePointRecord:
    """The LAS point records of ``scan`` (all of it, or one chunk) in ``layout``.

    The values that decided the standard dimensions are not checked again here; a writer that
    took the layout from a sample checks each chunk with :func:`check_layout_fits`.

    Raises
    ------
    ScanFormatError
        For a result whose ``fused_label`` holds a value that is no class (``path`` names the
        target file in the message).
    """
    record = laspy.ScaleAwarePointRecord.zeros(len(scan), header=layout.header)
    arr = record.array
    lo, scale = layout.offsets, layout.scale
    for i, axis in enumerate("XYZ"):
        arr[axis] = np.rint((scan.xyz[:, i] - lo[i]) / scale).astype(np.int32)
    if scan.rgb is not None:
        for i, channel in enumerate(_RGB):
            arr[channel] = scan.rgb[:, i].astype(np.uint16) * np.uint16(257)
    columns = {col.name: col for col in layout.columns}
    cls = _input_classification(scan, columns, layout)
    if layout.result:
        arr["classification"] = result_classification(
            scan.fields[RESULT_FIELD], scan.fields.get("stray"), path=path
        )
        if layout.input_classification and cls is not None:
            arr[INPUT_CLASSIFICATION] = cls
    elif cls is not None:
        arr["classification"] = cls
    if layout.std_intensity:
        arr["intensity"] = columns["intensity"].take(scan.fields).astype(np.uint16)
    for name, (dim, dtype) in layout.extras.items():
        arr[dim] = columns[name].take(scan.fields).astype(dtype)
    return record


def _input_classification(
    scan: Scan, columns: dict[str, FieldColumn], layout: LasLayout
) -> np.ndarray | None:
    """The classification of a scan's own: its labels (-1 as 255, or as the raw
    ``classification`` value where it has one), or that raw field; None when it has neither."""
    raw = columns["classification"].take(scan.fields) if layout.std_classification else None
    if scan.labels is None:
        return None if raw is None else raw.astype(np.uint8)
    cls = np.where(scan.labels < 0, 255, scan.labels).astype(np.uint8)
    if raw is not None:
        cls = np.where(scan.labels < 0, raw.astype(np.uint8), cls)
    return cls


def check_layout_fits(scan: Scan, layout: LasLayout, path: Path) -> None:
    """Refuse a chunk whose values the layout (made from a sample) cannot store exactly.

    Coordinates must fit 32-bit integers at the layout's scale and offsets, and fields put into
    the standard intensity or classification dimension must be whole numbers in their range.

    Raises
    ------
    ScanFormatError
        Naming what does not fit and what to do about it.
    """
    if len(scan):
        steps = (scan.xyz - layout.offsets) / layout.scale
        if float(np.abs(steps).max()) > 2**31 - 1:
            raise ScanFormatError(
                f"{path}: coordinates up to {scan.xyz.max(axis=0).tolist()} (from "
                f"{scan.xyz.min(axis=0).tolist()}) do not fit LAS's 32-bit integers at offsets "
                f"{layout.offsets.tolist()} and scale {layout.scale}; the bounds given for the "
                f"whole scan are wrong"
            )
    columns = {col.name: col for col in layout.columns}
    for name, flag, top in (
        ("intensity", layout.std_intensity, 65535),
        ("classification", layout.std_classification, 255),
    ):
        if flag and not _fits_uint(columns[name].take(scan.fields), top):
            raise ScanFormatError(
                f"{path}: field {name!r} went into LAS's standard {name} dimension because the "
                f"first chunk held whole numbers in 0..{top}, but a later chunk does not; "
                f"convert the field to float32 (stored as extra bytes) before writing"
            )


def write_las(
    scan: Scan, path: Path, *, compress: bool, progress: ProgressFn | None = None
) -> None:
    """Write LAS 1.4 point format 7, or 6 without colour (LAZ when ``compress``); a result's
    fused classes in classification (see :func:`las_layout`).

    Parameters
    ----------
    scan : Scan
    path : Path
        Target file (written atomically).
    compress : bool
        Write LAZ (lazrs backend).
    progress : ProgressFn, optional
        Receives ``("write", fraction)``.

    Raises
    ------
    ScanFormatError
        On a field LAS cannot store (dtype or name too long).
    """
    report(progress, "write", 0.0)
    if len(scan):
        lo, hi = scan.xyz.min(axis=0), scan.xyz.max(axis=0)
    else:
        lo = hi = np.zeros(3)
    layout = las_layout(scan, lo, hi, path)
    las = laspy.LasData(header=layout.header, points=las_record(scan, layout, path))
    report(progress, "write", 0.3)
    with atomic_open(path) as fh:
        try:
            las.write(fh, do_compress=compress, laz_backend=laz_backend(compress))
        except laspy.errors.LaspyException as exc:
            raise ScanFormatError(f"{path}: cannot write LAS: {exc}") from exc
    report(progress, "write", 1.0)


def laz_backend(compress: bool) -> laspy.LazBackend | None:
    """The LAZ backend jointseg writes with, or None for uncompressed LAS: lazrs compressing
    its chunks on every core where it can (the same bytes as one core's, 1.8x faster on 2
    cores), else lazrs on one."""
    if not compress:
        return None
    if laspy.LazBackend.LazrsParallel.is_available():
        return laspy.LazBackend.LazrsParallel
    return laspy.LazBackend.Lazrs
