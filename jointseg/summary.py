"""A short description of a scan: what `jointseg info` prints and the service stores."""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel

from jointseg.classes import class_name
from jointseg.scan import Scan
from jointseg.spacing import estimate_spacing


class FieldSummary(BaseModel):
    """Dtype, width and value range of one per-point field."""

    name: str
    dtype: str
    width: int
    min: float
    max: float


class ScanSummary(BaseModel):
    """Size, extent, density, fields and label histogram of a scan."""

    points: int
    source_format: str | None
    bounds_min: tuple[float, float, float]
    bounds_max: tuple[float, float, float]
    extent: tuple[float, float, float]
    spacing: float
    has_rgb: bool
    fields: list[FieldSummary]
    label_histogram: dict[str, int] | None


def summarise(scan: Scan) -> ScanSummary:
    """Describe ``scan``: bounds in metres, median point spacing, fields and label counts."""
    lo = scan.xyz.min(axis=0) if len(scan) else np.zeros(3)
    hi = scan.xyz.max(axis=0) if len(scan) else np.zeros(3)
    fields = []
    for name, arr in sorted(scan.fields.items()):
        finite = arr[np.isfinite(arr)] if np.issubdtype(arr.dtype, np.floating) else arr
        fields.append(
            FieldSummary(
                name=name,
                dtype=str(arr.dtype),
                width=1 if arr.ndim == 1 else int(arr.shape[1]),
                min=float(finite.min()) if finite.size else float("nan"),
                max=float(finite.max()) if finite.size else float("nan"),
            )
        )
    histogram = None
    if scan.labels is not None:
        values, counts = np.unique(scan.labels, return_counts=True)
        histogram = {_safe_name(int(v)): int(c) for v, c in zip(values, counts, strict=True)}
    return ScanSummary(
        points=len(scan),
        source_format=scan.source_format,
        bounds_min=_triple(lo),
        bounds_max=_triple(hi),
        extent=_triple(hi - lo),
        spacing=estimate_spacing(scan.xyz),
        has_rgb=scan.rgb is not None,
        fields=fields,
        label_histogram=histogram,
    )


def _safe_name(label: int) -> str:
    try:
        return class_name(label)
    except ValueError:
        return f"label_{label}"


def _triple(v: np.ndarray) -> tuple[float, float, float]:
    return float(v[0]), float(v[1]), float(v[2])
