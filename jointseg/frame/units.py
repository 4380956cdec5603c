"""Which length unit a scan's coordinates are in: from the file where it says so, else from the
scan's own scale.

LAS/LAZ files name their CRS's linear unit (an OGC WKT record, or GeoTIFF keys); E57 is metres
by definition. Other files say nothing, but rooms are much alike in height: a storey is 2-5 m
from floor to ceiling wherever it was built, so the extent along up, read in each candidate
unit, tells millimetres (2 800) from centimetres (280), feet (9) and metres (2.8).
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass

import numpy as np

#: Metres per unit.
UNITS: dict[str, float] = {
    "m": 1.0,
    "cm": 0.01,
    "mm": 0.001,
    "ft": 0.3048,
    "us-ft": 1200.0 / 3937.0,
    "in": 0.0254,
}
#: Typical floor-to-ceiling height (m) and the range a single storey's up-extent falls in.
STOREY_M = 2.8
STOREY_RANGE_M = (1.8, 6.0)
#: EPSG codes of the linear units GeoTIFF keys use.
_EPSG_UNITS = {9001: "m", 9002: "ft", 9003: "us-ft", 9036: "m", 9033: "us-ft"}
_PROJ_LINEAR_UNITS_KEY = 3076
_VERTICAL_UNITS_KEY = 4099
_ELLIPSOID = re.compile(r"(?:ELLIPSOID|SPHEROID)\[[^\[\]]*(?:\[[^\[\]]*\][^\[\]]*)*\]", re.I)
_WKT_UNIT = re.compile(r'(?:LENGTH)?UNIT\[\s*"([^"]+)"\s*,\s*([0-9.eE+-]+)', re.IGNORECASE)


@dataclass(frozen=True)
class UnitsDecision:
    """The unit chosen, metres per unit, how it was decided and how sure it is (0-1)."""

    unit: str
    metres: float
    how: str
    confidence: float


def unit_named(factor: float) -> str | None:
    """The unit whose metres-per-unit is ``factor`` (within 1e-6 relative), if any."""
    for name, metres in UNITS.items():
        if abs(factor - metres) <= 1e-6 * metres:
            return name
    return None


def unit_from_wkt(text: str) -> str | None:
    """The horizontal linear unit of an OGC WKT CRS (WKT1 or WKT2): its first length unit
    (angular units are skipped; a compound CRS names the horizontal part first)."""
    text = _ELLIPSOID.sub("", text)  # WKT2 gives the ellipsoid's axes a length unit of its own
    for name, factor in _WKT_UNIT.findall(text):
        try:
            value = float(factor)
        except ValueError:
            continue
        if "degree" in name.lower() or "radian" in name.lower() or "grad" in name.lower():
            continue
        unit = unit_named(value)
        if unit is not None:
            return unit  # the first length unit is the horizontal CRS's, before any VERT_CS
    return None


def unit_from_geokeys(data: bytes) -> str | None:
    """The linear unit from a GeoKeyDirectoryTag record (LAS record id 34735)."""
    if len(data) < 8:
        return None
    count = struct.unpack_from("<4H", data, 0)[3]
    keys = {}
    for i in range(count):
        off = 8 + 8 * i
        if off + 8 > len(data):
            break
        key, location, _, value = struct.unpack_from("<4H", data, off)
        if location == 0:
            keys[key] = value
    code = keys.get(_PROJ_LINEAR_UNITS_KEY, keys.get(_VERTICAL_UNITS_KEY))
    return None if code is None else _EPSG_UNITS.get(code)


def units_from_scale(up_extent: float) -> UnitsDecision:
    """The unit in which ``up_extent`` (the scan's robust extent along up, in file units) is
    most like a storey; metres are preferred up to the top of :data:`STOREY_RANGE_M`."""
    if up_extent <= 0:
        return UnitsDecision("m", 1.0, "assumed (the scan has no height)", 0.0)
    lo, hi = STOREY_RANGE_M
    in_m = up_extent
    if lo <= in_m <= hi:
        margin = min(np.log(in_m / lo), np.log(hi / in_m)) / np.log(hi / lo) * 2
        return UnitsDecision(
            "m", 1.0, f"scale: {in_m:.2f} m from floor to top", float(0.5 + 0.5 * margin)
        )
    # US survey feet differ from feet by 2 ppm: only a file's CRS can tell them apart
    guesses = [u for u in UNITS if u != "us-ft"]
    best = min(guesses, key=lambda u: abs(np.log(up_extent * UNITS[u] / STOREY_M)))
    height = up_extent * UNITS[best]
    off = abs(np.log(height / STOREY_M))
    confidence = float(np.clip(1.0 - off / np.log(hi / STOREY_M), 0.0, 1.0))
    return UnitsDecision(
        best, UNITS[best], f"scale: {height:.2f} m from floor to top in {best}", confidence
    )
