"""Geometric segmentation (§2.2): multi-level plane extraction, Euclidean clustering and
colour region growing, without semantics.

``segment`` and its result types are imported on first use (PEP 562), so ``GeometryParams``
alone (configuration files, the CLI, the service's request checks) does not load open3d. The
implementation lives in ``segmentation``, not in a module called ``segment``, so the submodule
never shadows the ``segment`` function on this package.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from jointseg.geometry.params import GeometryParams, ResolvedGeometryParams
from jointseg.lazy import lazy_attributes

if TYPE_CHECKING:
    from jointseg.geometry.segmentation import GeometryResult, PlaneInfo, scan_params, segment

_LAZY = ("GeometryResult", "PlaneInfo", "scan_params", "segment")

__all__ = [
    "GeometryParams",
    "GeometryResult",
    "PlaneInfo",
    "ResolvedGeometryParams",
    "scan_params",
    "segment",
]


__getattr__ = lazy_attributes(__name__, {name: "jointseg.geometry.segmentation" for name in _LAZY})
