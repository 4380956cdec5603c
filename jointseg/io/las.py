"""LAS / LAZ through laspy (LAZ with the lazrs backend).

Reading: coordinates with the header's scales and offsets applied; 16-bit colour divided by 257
(colour whose maximum is ≤ 255 is taken as 8-bit already; colour 0 everywhere means none);
classification becomes labels, with 255 meaning unlabelled and values above 12 read as
unlabelled too, the raw classification then also kept as field ``classification``. A
classification that is 0 everywhere in a file not written by jointseg means "never classified"
and gives no labels. ``intensity`` (unless 0 everywhere) and every extra-bytes dimension become
fields.

Writing: LAS 1.4, point format 7 (6 when the scan has no colour), scale 0.1 mm (coarser when the
extent needs it) with offsets at the minimum; colour × 257; labels in classification (-1 as 255)
and a small VLR saying so; every field as an extra-bytes dimension of its own dtype (a 2-D field
``f`` as ``f_0 .. f_{k-1}``). A field named ``intensity`` holding whole numbers in 0..65535 goes
into the standard intensity dimension; a field whose name is another standard dimension (or a
float intensity) is stored as ``extra_<name>``, which reads back as ``<name>`` from files written
by jointseg.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import laspy
import numpy as np

from jointseg.exceptions import ScanFormatError
from jointseg.io.atomic import atomic_open
from jointseg.io.common import (
    ScanInfo,
    build_scan,
    check_max_points,
    flatten_fields,
    normalise_labels,
    to_rgb8,
)
from jointseg.progress import ProgressFn, report
from jointseg.scan import Scan

logger = logging.getLogger(__name__)

#: VLR marking files whose classification holds S3DIS labels (written by jointseg).
LABELS_VLR_USER_ID = "jointseg"
LABELS_VLR_RECORD_ID = 1
_BASE_SCALE = 1e-4
_INT32_SPAN = 2**31 - 2
_LASPY_ERRORS = (laspy.errors.LaspyException, ValueError, OSError, EOFError, RuntimeError)
_EXTRA_KINDS = frozenset("iuf")


def _open(path: Path) -> laspy.LasReader:
    try:
        return laspy.open(str(path))
    except _LASPY_ERRORS as exc:
        with open(path, "rb") as fh:
            magic = fh.read(4)
        if magic != b"LASF":
            raise ScanFormatError(
                f"{path}: not a LAS/LAZ file (it does not start with the 'LASF' signature)"
            ) from exc
        raise ScanFormatError(f"{path}: cannot read the LAS header: {exc}") from exc


def _check_body_size(path: Path, header: laspy.LasHeader) -> None:
    """For uncompressed files, compare the byte size of the point block with the header's count."""
    if header.are_points_compressed:
        return
    record = header.point_format.size
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


def _labels_vlr(header: laspy.LasHeader) -> bool:
    return any(
        getattr(v, "user_id", "") == LABELS_VLR_USER_ID
        and getattr(v, "record_id", None) == LABELS_VLR_RECORD_ID
        for v in header.vlrs
    )


def _written_by_jointseg(header: laspy.LasHeader) -> bool:
    return str(header.generating_software).strip("\x00 ").startswith("jointseg")


def read_las(path: Path, *, max_points: int, progress: ProgressFn | None = None) -> Scan:
    """Read a LAS or LAZ file.

    Parameters
    ----------
    path : Path
    max_points : int
        Refuse files whose header declares more points (checked before the points are read).
    progress : ProgressFn, optional
        Receives ``("read", fraction)``.

    Returns
    -------
    Scan

    Raises
    ------
    ScanFormatError
        On a wrong signature, a point block shorter or longer than declared, a corrupt LAZ
        stream, non-finite coordinates or too many points.
    """
    report(progress, "read", 0.0)
    with _open(path) as reader:
        header = reader.header
        check_max_points(header.point_count, max_points, path)
        _check_body_size(path, header)
        try:
            points = reader.read_points(header.point_count)
        except _LASPY_ERRORS as exc:
            what = "decompress the LAZ" if header.are_points_compressed else "read the LAS"
            raise ScanFormatError(
                f"{path}: cannot {what} points (truncated or corrupt file?): {exc}"
            ) from exc
    if len(points) != header.point_count:
        raise ScanFormatError(
            f"{path}: truncated LAS: the header declares {header.point_count:,} points but "
            f"only {len(points):,} could be read"
        )
    report(progress, "read", 0.7)
    arr = points.array
    scales, offsets = header.scales, header.offsets
    xyz = np.empty((len(points), 3), dtype=np.float64)
    for i, axis in enumerate("XYZ"):
        np.multiply(arr[axis], scales[i], out=xyz[:, i])
        xyz[:, i] += offsets[i]
    dims = set(points.point_format.dimension_names)
    rgb = None
    if {"red", "green", "blue"} <= dims and (
        arr["red"].any() or arr["green"].any() or arr["blue"].any()
    ):
        rgb = to_rgb8(np.stack([arr["red"], arr["green"], arr["blue"]], axis=1), path=path)
    fields: dict[str, np.ndarray] = {}
    labels = None
    cls = np.asarray(points.classification)
    if _labels_vlr(header) or cls.any():
        labels, fields = normalise_labels(
            cls,
            path=path,
            source="classification",
            raw_field="classification",
            unlabelled_values=(255,),
        )
    intensity = np.asarray(arr["intensity"])
    if intensity.any():
        fields["intensity"] = intensity.copy()
    ours = _written_by_jointseg(header)
    for name in points.point_format.extra_dimension_names:
        key = name
        if ours and name.startswith("extra_") and name[6:] not in fields:
            key = name[6:]  # undo the renaming done by write_las
        fields[key] = np.array(points[name])
    report(progress, "read", 1.0)
    return build_scan(
        path, "laz" if header.are_points_compressed else "las", xyz, rgb, labels, fields
    )


def probe_las(path: Path, *, max_points: int) -> ScanInfo:
    """Check a LAS/LAZ header (and the point block size when uncompressed).

    Parameters
    ----------
    path : Path
    max_points : int

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
    with _open(path) as reader:
        header = reader.header
    check_max_points(header.point_count, max_points, path)
    _check_body_size(path, header)
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
        if "classification" in (dtype.names or ()):
            cls = block["classification"]
        else:
            cls = block["raw_classification"] & 0x1F
        has_labels = bool(cls.any())
        has_intensity = bool(block["intensity"].any())
        has_rgb = has_rgb and bool(
            block["red"].any() or block["green"].any() or block["blue"].any()
        )
        del block, cls
    has_labels = has_labels or _labels_vlr(header)
    ours = _written_by_jointseg(header)
    extra = [n[6:] if ours and n.startswith("extra_") else n for n in fmt.extra_dimension_names]
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


def write_las(
    scan: Scan, path: Path, *, compress: bool, progress: ProgressFn | None = None
) -> None:
    """Write LAS 1.4 point format 7, or 6 without colour (LAZ when ``compress``).

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
    header = laspy.LasHeader(point_format=7 if scan.rgb is not None else 6, version="1.4")
    header.generating_software = "jointseg"
    standard = {d.lower() for d in header.point_format.dimension_names} | {"x", "y", "z"}
    n = len(scan)
    if n:
        lo, hi = scan.xyz.min(axis=0), scan.xyz.max(axis=0)
    else:
        lo = hi = np.zeros(3)
    scale = _BASE_SCALE
    while float((hi - lo).max()) / scale > _INT32_SPAN:
        scale *= 10.0
    header.scales = np.full(3, scale)
    header.offsets = lo
    fields = flatten_fields(scan.fields, path=path)
    intensity = fields.get("intensity")
    std_intensity = intensity is not None and _fits_uint(intensity, 65535)
    raw_cls = fields.get("classification")
    std_cls = raw_cls is not None and _fits_uint(raw_cls, 255)
    extras: dict[str, np.ndarray] = {}
    for name, values in fields.items():
        if (name == "intensity" and std_intensity) or (name == "classification" and std_cls):
            continue
        if values.dtype.kind == "b":
            values = values.astype(np.uint8)
        elif values.dtype.kind == "f" and values.dtype.itemsize == 2:
            values = values.astype(np.float32)
        if values.dtype.kind not in _EXTRA_KINDS or values.dtype.itemsize > 8:
            raise ScanFormatError(
                f"{path}: field {name!r} has dtype {values.dtype}; LAS extra bytes hold only "
                f"integers and float32/float64"
            )
        extras[_extra_name(name, standard, path)] = values.astype(values.dtype.newbyteorder("<"))
    if extras:
        header.add_extra_dims(
            [laspy.ExtraBytesParams(name=k, type=v.dtype) for k, v in extras.items()]
        )
    if scan.labels is not None:
        header.vlrs.append(
            laspy.VLR(
                user_id=LABELS_VLR_USER_ID,
                record_id=LABELS_VLR_RECORD_ID,
                description="classification = S3DIS labels",
                record_data=b"",
            )
        )
    record = laspy.ScaleAwarePointRecord.zeros(n, header=header)
    arr = record.array
    for i, axis in enumerate("XYZ"):
        arr[axis] = np.rint((scan.xyz[:, i] - lo[i]) / scale).astype(np.int32)
    if scan.rgb is not None:
        for i, channel in enumerate(("red", "green", "blue")):
            arr[channel] = scan.rgb[:, i].astype(np.uint16) * np.uint16(257)
    if scan.labels is not None:
        cls = np.where(scan.labels < 0, 255, scan.labels).astype(np.uint8)
        if std_cls:
            assert raw_cls is not None
            cls = np.where(scan.labels < 0, raw_cls.astype(np.uint8), cls)
        arr["classification"] = cls
    elif std_cls:
        assert raw_cls is not None
        arr["classification"] = raw_cls.astype(np.uint8)
    if std_intensity:
        assert intensity is not None
        arr["intensity"] = intensity.astype(np.uint16)
    for name, values in extras.items():
        arr[name] = values
    las = laspy.LasData(header=header, points=record)
    report(progress, "write", 0.3)
    with atomic_open(path) as fh:
        try:
            las.write(
                fh, do_compress=compress, laz_backend=laspy.LazBackend.Lazrs if compress else None
            )
        except laspy.errors.LaspyException as exc:
            raise ScanFormatError(f"{path}: cannot write LAS: {exc}") from exc
    report(progress, "write", 1.0)
