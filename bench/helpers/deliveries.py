"""Scans as users deliver them (issue 31): one clean room in another axis convention, unit or
georeferenced frame, tilted, with stray points, without or with poor colour, noisier, or as one
depth camera's view of it in the camera's frame, written to a real file (PLY, or LAS 1.4 with
scale, offsets and a CRS) with no ground truth in it.

Every maker takes the clean room (``xyz`` float64 (N, 3), metres, z up; ``rgb`` uint8 (N, 3) or
None) and a numpy Generator and returns a :class:`Delivery`: the new coordinates and colour,
which clean point each new point is (``source``, -1 for an added point) and what was done
(``info``). :func:`deliver` chains makers and tracks the truth a frame detector should find
(up axis in the file's axes, tilt, units, stray count); :func:`write_delivery` writes the file
and :func:`file_xyz` reads its coordinates back without jointseg, in the file's own units.

The up-axis fit's own deliveries (axis conventions, tilt, a slice, half a room, camera views,
made in memory) are :mod:`jointseg.fitting.up_axis_cases`'s, which ``bench/up_axis.py`` and
``bench/frame_calibration.py`` use; this module adds what only a written file shows (units,
georeferenced offsets and CRS in LAS, stray points, colour) and names the truth as they do.

Nothing here knows where scans live, so the test suite can use the makers on synthetic rooms:

>>> rng = np.random.default_rng(0)                                       # doctest: +SKIP
>>> d = deliver(VARIANTS["combo"].steps, xyz, rgb, rng)                  # doctest: +SKIP
>>> written = write_delivery(d, folder / "combo", VARIANTS["combo"])     # doctest: +SKIP
>>> gt = np.where(d.source >= 0, labels[np.maximum(d.source, 0)], -1)    # doctest: +SKIP
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import laspy
import numpy as np
from laspy.vlrs.known import WktCoordinateSystemVlr

from jointseg.fitting.up_axis_cases import nearest_axis as fit_nearest_axis
from jointseg.frame.decide import rotation_about
from jointseg.io import write_scan
from jointseg.io.units import UNITS
from jointseg.scan import Scan
from jointseg.synth.views import camera_view

#: US survey feet per metre (1 ftUS = 1200/3937 m) and international feet per metre.
FT_US_PER_M = 1.0 / UNITS["us-ft"]
FT_PER_M = 1.0 / UNITS["ft"]

#: EPSG:2227, NAD83 / California zone 3 (ftUS), as OGC WKT 1 (what pyproj would write; pyproj
#: is not installed, so the record is written as text). Its linear unit is the US survey foot.
WKT_EPSG_2227 = (
    'PROJCS["NAD83 / California zone 3 (ftUS)",GEOGCS["NAD83",DATUM["North_American_Datum_1983",'
    'SPHEROID["GRS 1980",6378137,298.257222101,AUTHORITY["EPSG","7019"]],'
    'TOWGS84[0,0,0,0,0,0,0],AUTHORITY["EPSG","6269"]],PRIMEM["Greenwich",0,'
    'AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],'
    'AUTHORITY["EPSG","4269"]],PROJECTION["Lambert_Conformal_Conic_2SP"],'
    'PARAMETER["standard_parallel_1",38.43333333333333],'
    'PARAMETER["standard_parallel_2",37.06666666666667],PARAMETER["latitude_of_origin",36.5],'
    'PARAMETER["central_meridian",-120.5],PARAMETER["false_easting",6561666.667],'
    'PARAMETER["false_northing",1640416.667],'
    'UNIT["US survey foot",0.3048006096012192,AUTHORITY["EPSG","9003"]],'
    'AXIS["X",EAST],AXIS["Y",NORTH],AUTHORITY["EPSG","2227"]]'
)
#: EPSG:26910, NAD83 / UTM zone 10N, as OGC WKT 1: metres.
WKT_EPSG_26910 = (
    'PROJCS["NAD83 / UTM zone 10N",GEOGCS["NAD83",DATUM["North_American_Datum_1983",'
    'SPHEROID["GRS 1980",6378137,298.257222101,AUTHORITY["EPSG","7019"]],'
    'TOWGS84[0,0,0,0,0,0,0],AUTHORITY["EPSG","6269"]],PRIMEM["Greenwich",0,'
    'AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,AUTHORITY["EPSG","9122"]],'
    'AUTHORITY["EPSG","4269"]],PROJECTION["Transverse_Mercator"],'
    'PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",-123],'
    'PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],'
    'PARAMETER["false_northing",0],UNIT["metre",1,AUTHORITY["EPSG","9001"]],'
    'AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","26910"]]'
)


@dataclass(frozen=True)
class Delivery:
    """A room as delivered.

    Attributes
    ----------
    xyz : ndarray of shape (M, 3), float64
        Coordinates in the delivery's own axes and units.
    rgb : ndarray of shape (M, 3), uint8, or None
    source : ndarray of shape (M,), int64
        The clean point each point is; -1 for an added (stray) point.
    info : dict
        What the makers did; after :func:`deliver`, the truth too: ``up`` (unit vector in the
        file's axes), ``up_axis`` ('+y', ...), ``tilt_degrees``, ``units`` ('m', 'mm', 'ft',
        'ftUS'), ``scale`` (file units per metre), ``offset``, ``strays``, ``colour``, ``steps``.
    """

    xyz: np.ndarray
    rgb: np.ndarray | None
    source: np.ndarray
    info: dict[str, Any] = field(default_factory=dict)


Maker = Callable[[np.ndarray, np.ndarray | None, np.random.Generator], Delivery]


def _same(xyz: np.ndarray, rgb: np.ndarray | None, **info: Any) -> Delivery:
    return Delivery(xyz, rgb, np.arange(len(xyz), dtype=np.int64), info)


# --- axes ----------------------------------------------------------------------------------

#: (x, y, z) -> (x, z, -y): y up, as glTF and many mesh tools write.
Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: (x, y, z) -> (x, -y, -z): upside down.
Z_DOWN = np.diag([1.0, -1.0, -1.0])
#: (x, y, z) -> (z, x, y): x up.
X_UP = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def rotated(
    xyz: np.ndarray,
    rgb: np.ndarray | None,
    rng: np.random.Generator,
    *,
    matrix: np.ndarray,
    name: str = "rotated",
) -> Delivery:
    """``xyz @ matrix.T`` about the origin: an exporter's change of axis convention."""
    matrix = np.asarray(matrix, dtype=np.float64)
    return _same(xyz @ matrix.T, rgb, rotation=matrix, step=name)


y_up: Maker = functools.partial(rotated, matrix=Y_UP, name="y up")
z_down: Maker = functools.partial(rotated, matrix=Z_DOWN, name="z down")
x_up: Maker = functools.partial(rotated, matrix=X_UP, name="x up")


def tilted(
    xyz: np.ndarray, rgb: np.ndarray | None, rng: np.random.Generator, *, degrees: float = 5.0
) -> Delivery:
    """Rotated by ``degrees`` about a random horizontal axis through the box centre: a scanner
    that was not levelled."""
    phi = rng.uniform(0.0, 2.0 * np.pi)
    matrix = rotation_about(np.array([np.cos(phi), np.sin(phi), 0.0]), degrees)
    centre = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
    return _same((xyz - centre) @ matrix.T + centre, rgb, rotation=matrix, step=f"tilt {degrees}")


# --- units and frame -----------------------------------------------------------------------


def scaled(
    xyz: np.ndarray,
    rgb: np.ndarray | None,
    rng: np.random.Generator,
    *,
    factor: float,
    units: str,
) -> Delivery:
    """Coordinates in another unit: ``factor`` file units per metre."""
    return _same(xyz * factor, rgb, scale=factor, units=units, step=units)


millimetres: Maker = functools.partial(scaled, factor=1000.0, units="mm")
us_survey_feet: Maker = functools.partial(scaled, factor=FT_US_PER_M, units="ftUS")
feet: Maker = functools.partial(scaled, factor=FT_PER_M, units="ft")


def shifted(
    xyz: np.ndarray, rgb: np.ndarray | None, rng: np.random.Generator, *, offset: tuple
) -> Delivery:
    """Moved by ``offset`` (file units): a georeferenced frame (UTM, state plane)."""
    off = np.asarray(offset, dtype=np.float64)
    return _same(xyz + off, rgb, offset=off, step="offset")


# --- points --------------------------------------------------------------------------------


def strays(
    xyz: np.ndarray,
    rgb: np.ndarray | None,
    rng: np.random.Generator,
    *,
    share: float = 0.003,
    near: float = 2.0,
    far: float = 10.0,
) -> Delivery:
    """``share`` extra points ``near``-``far`` metres outside the box (below the floor, beyond
    a wall, above the ceiling), random colours, mixed in at random places (``source`` -1).

    Works in the clean room's frame (metres, z up): apply it before axis or unit changes.
    """
    n = len(xyz)
    m = max(1, round(share * n))
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    extra = rng.uniform(lo, hi, size=(m, 3))
    side = rng.integers(0, 6, size=m)  # 0/1: below/above, 2..5: beyond the -x, +x, -y, +y wall
    dist = rng.uniform(near, far, size=m)
    axis = np.where(side < 2, 2, (side - 2) // 2)
    upper = np.where(side < 2, side == 1, (side - 2) % 2 == 1)
    rows = np.arange(m)
    extra[rows, axis] = np.where(upper, hi[axis] + dist, lo[axis] - dist)
    total = n + m
    at = np.sort(rng.choice(total, size=m, replace=False))
    is_extra = np.zeros(total, dtype=bool)
    is_extra[at] = True
    source = np.full(total, -1, dtype=np.int64)
    source[~is_extra] = np.arange(n)
    out = np.empty((total, 3))
    out[~is_extra] = xyz
    out[is_extra] = extra
    colour = None
    if rgb is not None:
        colour = np.empty((total, 3), dtype=np.uint8)
        colour[~is_extra] = rgb
        colour[is_extra] = rng.integers(0, 256, size=(m, 3), dtype=np.uint8)
    below, above = int((side == 0).sum()), int((side == 1).sum())
    return Delivery(
        out,
        colour,
        source,
        {
            "step": "strays",
            "strays": m,
            "below": below,
            "above": above,
            "beyond walls": m - below - above,
        },
    )


def noisy(
    xyz: np.ndarray, rgb: np.ndarray | None, rng: np.random.Generator, *, sigma: float = 0.005
) -> Delivery:
    """Gaussian noise of ``sigma`` (metres) per axis: a cheaper sensor."""
    return _same(xyz + rng.normal(0.0, sigma, size=xyz.shape), rgb, step=f"noise {sigma}")


# --- colour --------------------------------------------------------------------------------


def no_colour(xyz: np.ndarray, rgb: np.ndarray | None, rng: np.random.Generator) -> Delivery:
    """Colour dropped: the file holds x y z only."""
    return _same(xyz, None, colour="none", step="no colour")


def constant_colour(
    xyz: np.ndarray, rgb: np.ndarray | None, rng: np.random.Generator, *, value: int = 128
) -> Delivery:
    """Every point the same grey: a scanner without a camera that fills the fields anyway."""
    return _same(
        xyz, np.full((len(xyz), 3), value, dtype=np.uint8), colour=f"constant {value}", step="grey"
    )


def colour_gains(
    xyz: np.ndarray,
    rgb: np.ndarray | None,
    rng: np.random.Generator,
    *,
    gains: tuple[float, float, float],
    name: str = "gains",
) -> Delivery:
    """Each channel times its gain, rounded and clipped to 0..255 (no colour stays none)."""
    if rgb is None:
        return _same(xyz, None, colour=name, step=name)
    out = np.clip(np.rint(rgb.astype(np.float64) * np.asarray(gains)), 0, 255).astype(np.uint8)
    return _same(xyz, out, colour=name, step=name)


dim: Maker = functools.partial(colour_gains, gains=(0.45, 0.45, 0.45), name="dim x0.45")
tint: Maker = functools.partial(colour_gains, gains=(1.2, 1.0, 0.8), name="tint r1.2 b0.8")


# --- chaining ------------------------------------------------------------------------------

AXIS_NAMES = ("x", "y", "z")


def nearest_axis(up: np.ndarray) -> tuple[str, float]:
    """The signed file axis nearest to ``up`` ('+z', '-y', ...), named as the up-axis fit's
    cases name it (:func:`jointseg.fitting.up_axis_cases.nearest_axis`), and the angle to it
    (deg)."""
    i = int(np.argmax(np.abs(up)))
    cos = min(1.0, abs(float(up[i])) / float(np.linalg.norm(up)))
    return fit_nearest_axis(up), float(np.degrees(np.arccos(cos)))


def camera_frame(xyz: np.ndarray, rgb: np.ndarray | None, rng: np.random.Generator) -> Delivery:
    """One depth camera's view of the room, in the camera's frame (x right, y down, z forward):
    held 1.0-1.7 m up inside the room, pitched -25 to +10 deg, rolled up to 5 deg, 58 x 45 deg,
    only the nearest surface per pixel (jointseg.synth.views)."""
    view = camera_view(Scan(np.asarray(xyz, dtype=np.float64), rgb), rng)
    if view is None:
        raise ValueError("no camera view of this room sees 2 000 points")
    info = {"rotation": view.rotation, "offset": -(view.rotation @ view.eye), "step": "camera"}
    return Delivery(view.scan.xyz, view.scan.rgb, view.points.astype(np.int64), info)


def deliver(
    steps: tuple[Maker, ...],
    xyz: np.ndarray,
    rgb: np.ndarray | None,
    rng: np.random.Generator,
) -> Delivery:
    """Apply ``steps`` in order to the clean room; ``source`` maps to the clean points and
    ``info`` holds the truth (see :class:`Delivery`)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    source = np.arange(len(xyz), dtype=np.int64)
    up = np.array([0.0, 0.0, 1.0])
    truth: dict[str, Any] = {
        "units": "m",
        "scale": 1.0,
        "offset": np.zeros(3),
        "strays": 0,
        "colour": "as scanned" if rgb is not None else "none",
        "steps": [],
    }
    for step in steps:
        d = step(xyz, rgb, rng)
        source = np.where(d.source >= 0, source[np.maximum(d.source, 0)], -1)
        xyz, rgb = d.xyz, d.rgb
        if "rotation" in d.info:
            rot = d.info["rotation"]
            up = rot @ up
            truth["offset"] = rot @ truth["offset"]
        if "scale" in d.info:
            truth["scale"] *= d.info["scale"]
            truth["units"] = d.info["units"]
            truth["offset"] = truth["offset"] * d.info["scale"]
        if "offset" in d.info:
            truth["offset"] = truth["offset"] + d.info["offset"]
        truth["strays"] += int(d.info.get("strays", 0))
        if "colour" in d.info:
            truth["colour"] = d.info["colour"]
        truth["steps"].append(d.info.get("step", getattr(step, "__name__", "step")))
    axis, tilt = nearest_axis(up)
    truth.update(up=up, up_axis=axis, tilt_degrees=tilt)
    return Delivery(xyz, rgb, source, truth)


# --- variants and files --------------------------------------------------------------------


@dataclass(frozen=True)
class LasSpec:
    """How a delivery is written as LAS 1.4: coordinate ``scale`` (file units), offsets at the
    minimum rounded down to a multiple of ``offset_step``, and an OGC WKT CRS (or none)."""

    scale: float
    crs_wkt: str | None = None
    offset_step: float = 1000.0


@dataclass(frozen=True)
class Variant:
    """A way users deliver scans: the makers, in order, and the file (PLY unless ``las``)."""

    steps: tuple[Maker, ...]
    what: str
    las: LasSpec | None = None

    @property
    def suffix(self) -> str:
        return ".las" if self.las is not None else ".ply"


def _p(fn: Callable[..., Delivery], **kw: Any) -> Maker:
    return functools.partial(fn, **kw)


#: State-plane offsets of the usft variant (feet: easting, northing, elevation).
STATE_PLANE_OFFSET = (6_000_000.0, 2_000_000.0, 330.0)
#: UTM-like offsets of the georef variant (metres).
UTM_OFFSET = (500_000.0, 4_200_000.0, 100.0)

VARIANTS: dict[str, Variant] = {
    "clean": Variant((), "as scanned, PLY"),
    "yup": Variant((y_up,), "y up (x, z, -y), glTF style"),
    "zdown": Variant((z_down,), "upside down (x, -y, -z)"),
    "xup": Variant((x_up,), "x up (z, x, y)"),
    "tilt": Variant((_p(tilted, degrees=5.0),), "5 deg about a random horizontal axis"),
    "tilt15": Variant((_p(tilted, degrees=15.0),), "15 deg about a random horizontal axis"),
    "mm": Variant((millimetres,), "millimetres, PLY double"),
    "usft": Variant(
        (us_survey_feet, _p(shifted, offset=STATE_PLANE_OFFSET)),
        "US survey feet + state-plane offsets, LAS 1.4 with EPSG:2227 WKT, scale 0.01 ft",
        LasSpec(0.01, WKT_EPSG_2227),
    ),
    "ft_nocrs": Variant((feet,), "international feet, PLY, no metadata"),
    "georef": Variant(
        (_p(shifted, offset=UTM_OFFSET),),
        "metres + UTM-like offsets, LAS 1.4 with EPSG:26910 WKT, scale 0.001",
        LasSpec(0.001, WKT_EPSG_26910),
    ),
    "stray": Variant((strays,), "0.3% stray points 2-10 m outside the box"),
    "nocolour": Variant((no_colour,), "x y z only"),
    "constcolour": Variant((constant_colour,), "every point grey 128"),
    "noise": Variant((noisy,), "Gaussian noise 5 mm per axis"),
    "dim": Variant((dim,), "colour x0.45"),
    "tint": Variant((tint,), "white balance: red x1.2, blue x0.8"),
    "camera": Variant((camera_frame,), "one depth camera view, in the camera's frame, PLY"),
    "combo": Variant((strays, y_up, millimetres, no_colour), "0.3% strays + y up + mm + no colour"),
}


def write_delivery(delivery: Delivery, stem: Path, variant: Variant) -> Path:
    """Write ``delivery`` to ``stem`` + the variant's suffix and return the path.

    PLY goes through jointseg.io's writer (binary, double coordinates, uchar colour when there
    is colour, nothing else); LAS through laspy: 1.4, point format 7 (6 without colour),
    the variant's scale, offsets and WKT CRS (global encoding's WKT bit set).
    """
    path = stem.with_name(stem.name + variant.suffix)
    if variant.las is None:
        write_scan(Scan(delivery.xyz, delivery.rgb), path)
        return path
    spec = variant.las
    rgb = delivery.rgb
    header = laspy.LasHeader(point_format=7 if rgb is not None else 6, version="1.4")
    header.generating_software = "jointseg bench deliveries"
    header.scales = np.full(3, spec.scale)
    header.offsets = np.floor(delivery.xyz.min(axis=0) / spec.offset_step) * spec.offset_step
    if spec.crs_wkt is not None:
        header.vlrs.append(WktCoordinateSystemVlr(spec.crs_wkt))
        header.global_encoding.wkt = True
    las = laspy.LasData(header)
    las.x, las.y, las.z = delivery.xyz[:, 0], delivery.xyz[:, 1], delivery.xyz[:, 2]
    if rgb is not None:
        wide = rgb.astype(np.uint16) * np.uint16(257)
        las.red, las.green, las.blue = wide[:, 0], wide[:, 1], wide[:, 2]
    las.write(str(path))
    return path


def file_xyz(path: Path) -> np.ndarray:
    """The coordinates stored in a PLY or LAS/LAZ file, read with plyfile or laspy (not
    jointseg), in the file's own units and frame (LAS: integers x scale + offset)."""
    if path.suffix.lower() in (".las", ".laz"):
        las = laspy.read(str(path))
        return np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    from plyfile import PlyData

    vertex = PlyData.read(str(path))["vertex"].data
    return np.column_stack([vertex[a].astype(np.float64) for a in AXIS_NAMES])
