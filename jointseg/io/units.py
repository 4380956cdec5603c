"""Length units a file names: the linear unit of a LAS/LAZ file's CRS, from its OGC WKT record
or its GeoTIFF keys (E57 is metres by definition).

Why in io: reading what a file says about itself is the reader's job; the frame stage decides
the unit of a scan that says nothing (:mod:`jointseg.frame.units`) and takes this table from
here.
"""

from __future__ import annotations

import re
import struct

#: Metres per unit.
UNITS: dict[str, float] = {
    "m": 1.0,
    "cm": 0.01,
    "mm": 0.001,
    "ft": 0.3048,
    "us-ft": 1200.0 / 3937.0,
    "in": 0.0254,
}
#: EPSG codes of the linear units GeoTIFF keys use.
_EPSG_UNITS = {9001: "m", 9002: "ft", 9003: "us-ft", 9036: "m", 9033: "us-ft"}
_PROJ_LINEAR_UNITS_KEY = 3076
_VERTICAL_UNITS_KEY = 4099
_ELLIPSOID = re.compile(r"(?:ELLIPSOID|SPHEROID)\[[^\[\]]*(?:\[[^\[\]]*\][^\[\]]*)*\]", re.I)
_WKT_UNIT = re.compile(r'(?:LENGTH)?UNIT\[\s*"([^"]+)"\s*,\s*([0-9.eE+-]+)', re.IGNORECASE)


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
