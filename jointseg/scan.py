"""The one data type that flows through the method."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from jointseg.exceptions import ScanFormatError

#: Field names that are carried by dedicated attributes, never by ``Scan.fields``.
RESERVED_FIELDS = frozenset({"x", "y", "z", "red", "green", "blue", "label"})


@dataclass(frozen=True, eq=False)
class Scan:
    """A point cloud with optional colour, ground-truth labels and extra per-point fields.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), float64, metres
        Finite coordinates.
    rgb : ndarray of shape (N, 3), uint8, optional
    labels : ndarray of shape (N,), int32, optional
        S3DIS class indices, -1 = unlabelled.
    fields : dict of str to ndarray of shape (N,) or (N, k)
        Named per-point attributes (intensity, segment, network_label, ...).
    source_format : str, optional
        The format the scan was read from (``"ply"``, ``"las"``, ...).
    meta : dict, optional
        What the file says about the whole scan rather than its points: ``units`` (the length
        unit the file declares, e.g. ``"us-ft"``) with ``units_source`` (where it says so), and
        ``las`` (a LAS/LAZ input's scales, offsets and CRS records, so an output keeps them).

    Notes
    -----
    Arrays are converted to the dtypes above and checked for shape once, here; after that every
    stage may rely on them. Inputs are copied only when a conversion is needed.

    Raises
    ------
    ScanFormatError
        On wrong shapes, mismatched lengths or non-finite coordinates.
    """

    xyz: np.ndarray
    rgb: np.ndarray | None = None
    labels: np.ndarray | None = None
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    source_format: str | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        xyz = np.asarray(self.xyz)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ScanFormatError(f"xyz must have shape (N, 3), got {xyz.shape}")
        xyz = np.ascontiguousarray(xyz, dtype=np.float64)
        if not np.isfinite(xyz).all():
            bad = int(np.flatnonzero(~np.isfinite(xyz).all(axis=1))[0])
            raise ScanFormatError(
                f"coordinates must be finite: point {bad} is {xyz[bad].tolist()} (NaN or inf)"
            )
        n = xyz.shape[0]
        object.__setattr__(self, "xyz", xyz)
        if self.rgb is not None:
            rgb = np.asarray(self.rgb)
            if rgb.shape != (n, 3):
                raise ScanFormatError(f"rgb must have shape ({n}, 3), got {rgb.shape}")
            if rgb.dtype != np.uint8:
                rgb = np.clip(rgb, 0, 255).astype(np.uint8)
            object.__setattr__(self, "rgb", np.ascontiguousarray(rgb))
        if self.labels is not None:
            labels = np.asarray(self.labels)
            if labels.shape != (n,):
                raise ScanFormatError(f"labels must have shape ({n},), got {labels.shape}")
            object.__setattr__(self, "labels", np.ascontiguousarray(labels, dtype=np.int32))
        checked: dict[str, np.ndarray] = {}
        for name, values in self.fields.items():
            arr = np.asarray(values)
            if name in RESERVED_FIELDS:
                raise ScanFormatError(f"field name {name!r} is reserved (use xyz/rgb/labels)")
            if arr.ndim not in (1, 2) or arr.shape[0] != n:
                raise ScanFormatError(
                    f"field {name!r} must have {n} rows (one per point), got shape {arr.shape}"
                )
            checked[name] = arr
        object.__setattr__(self, "fields", checked)

    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def n_points(self) -> int:
        """Number of points."""
        return len(self)

    def subset(self, index: np.ndarray) -> Scan:
        """A new scan with the points selected by ``index`` (boolean mask or integer indices)."""
        return Scan(
            xyz=self.xyz[index],
            rgb=None if self.rgb is None else self.rgb[index],
            labels=None if self.labels is None else self.labels[index],
            fields={k: v[index] for k, v in self.fields.items()},
            source_format=self.source_format,
            meta=self.meta,
        )

    def with_fields(self, **fields: np.ndarray) -> Scan:
        """A new scan with ``fields`` added to (or replacing) the extra fields."""
        merged = dict(self.fields)
        merged.update(fields)
        return Scan(self.xyz, self.rgb, self.labels, merged, self.source_format, self.meta)
