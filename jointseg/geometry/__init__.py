"""Geometric segmentation (§2.2): multi-level plane extraction, Euclidean clustering and
colour region growing, without semantics."""

from jointseg.geometry.params import GeometryParams, ResolvedGeometryParams
from jointseg.geometry.segment import GeometryResult, PlaneInfo, segment

__all__ = ["GeometryParams", "GeometryResult", "PlaneInfo", "ResolvedGeometryParams", "segment"]
