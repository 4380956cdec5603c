"""The frame stage: decide once, from the scan and its file, how to put it into the frame the
network and the geometry expect (z up and level, metres, stray points aside, colour as trained
on); then run the method there and carry every per-point result back to the user's points.

The stage only decides a transform. The user's own coordinates are never changed: outputs are
the input scan plus fields, so they stay bit-exact.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from jointseg.exceptions import ConfigError
from jointseg.frame import gravity
from jointseg.frame.colour import ColourDecision, apply_gains, decide_colour
from jointseg.frame.params import FrameParams
from jointseg.frame.strays import find_strays
from jointseg.frame.units import UNITS, UnitsDecision, units_from_scale
from jointseg.scan import Scan

log = logging.getLogger(__name__)

#: Tilts below this (degrees) are left alone: levelling a level scan would only move its labels.
MIN_TILT_DEGREES = 1.0
#: A scan less tall than this (m) along the up found is a slice or fragment, not a room: its
#: up is the file's own +z.
MIN_ROOM_HEIGHT_M = 1.5
#: Heights (m) along up outside this range are no building's: the units must be wrong.
MIN_PLAUSIBLE_M, MAX_PLAUSIBLE_M = 0.05, 200.0
#: Decisions less sure than this are reported as warnings.
UNSURE = 0.6


@dataclass(frozen=True)
class Frame:
    """The transform from the file's coordinates to the working frame, and what it set aside.

    ``work = metres * (xyz - origin) @ rotation.T``; ``stray`` marks the points left out of
    the work scan; ``identity`` when nothing changes (the scan is used as it is).
    """

    rotation: np.ndarray
    metres: float
    origin: np.ndarray
    stray: np.ndarray
    colour: ColourDecision
    up: gravity.UpEstimate
    up_how: str
    units: UnitsDecision
    levelled: bool
    identity: bool
    warnings: list[str] = field(default_factory=list)

    def to_work(self, xyz: np.ndarray) -> np.ndarray:
        """File coordinates to the working frame (z up, metres)."""
        if self.identity:
            return xyz
        return ((xyz - self.origin) @ self.rotation.T) * self.metres

    def matrix(self) -> list[list[float]]:
        """The 4x4 affine matrix of :meth:`to_work`, as nested lists."""
        m = np.eye(4)
        m[:3, :3] = self.rotation * self.metres
        m[:3, 3] = -(self.rotation @ self.origin) * self.metres
        return m.tolist()

    def report(self) -> dict[str, Any]:
        """The ``frame`` section of report.json."""
        return {
            "up": {
                "axis": self.up.axis,
                "tilt_degrees": round(self.up.tilt_degrees, 2),
                "levelled": self.levelled,
                "how": self.up_how,
                "confidence": round(self.up.confidence, 3),
            },
            "units": {
                "unit": self.units.unit,
                "metres_per_unit": self.units.metres,
                "how": self.units.how,
                "confidence": round(self.units.confidence, 3),
            },
            "stray_points": int(self.stray.sum()),
            "colour": {
                "kind": self.colour.kind,
                "gains": None
                if self.colour.gains is None
                else np.round(self.colour.gains, 3).tolist(),
            },
            "to_work": self.matrix(),
            "identity": self.identity,
            "warnings": list(self.warnings),
        }

    def summary(self) -> str:
        """One line for the command line and the log."""
        return summary_line(self.report())


def summary_line(frame: dict[str, Any]) -> str:
    """A report's frame section in one line (the CLI prints it, the log keeps it)."""
    up, units = frame["up"], frame["units"]
    tilt = f", levelled {up['tilt_degrees']:.1f} deg" if up["levelled"] else ""
    colour = frame["colour"]["kind"]
    return (
        f"frame: up {up['axis']} ({up['how']}, {up['confidence']:.2f}{tilt}); units "
        f"{units['unit']} ({units['how']}); {frame['stray_points']:,} stray points; colour "
        f"{colour}{' corrected' if frame['colour']['gains'] else ''}"
    )


def rotation_about(axis: np.ndarray, degrees: float) -> np.ndarray:
    """The rotation by ``degrees`` about ``axis`` (Rodrigues' formula)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    a = np.radians(degrees)
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(a) * cross + (1.0 - np.cos(a)) * cross @ cross


def rotation_to_z(up: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``up`` to +z (180 degrees about x for -z)."""
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(up, z)
    c = float(up @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + k + k @ k * (1.0 / (1.0 + c))


def decide_frame(scan: Scan, params: FrameParams | None = None) -> Frame:
    """Decide up, tilt, units, stray points and colour for ``scan``.

    Raises
    ------
    ConfigError
        For a scan too small or too flat to place (fewer than 20 distinct voxels).
    """
    params = params or FrameParams()
    rng = np.random.default_rng(0)
    centre = np.median(scan.xyz[:: max(1, len(scan) // 100_000)], axis=0)
    sample = gravity.frame_sample(scan.xyz - centre, rng)
    warnings: list[str] = []
    if params.up == "auto":
        axis, axis_p = gravity.vertical_axis(sample)
    else:
        axis, axis_p = "xyz".index(params.up[1]), np.eye(3)["xyz".index(params.up[1])]
    units = _units(scan, params, sample, axis)
    height = sample.extent(sample.directions[axis]) * units.metres
    if params.up == "auto" and height >= MIN_ROOM_HEIGHT_M:
        up = gravity.estimate_up(sample, axis, axis_p, units.metres)
        how = "scan geometry"
    elif params.up == "auto":
        # a slice or a fragment, not a room: floor, ceiling and furniture heights say nothing
        up = _given(sample, "+z", False, confidence=0.5)  # nor levelled: too little to level by
        how = f"the file's own (a partial scan, {height:.2f} m tall: too little to tell)"
    else:
        up = _given(sample, params.up, params.level, confidence=1.0)
        how = "set by the user"
    levelled = params.level and up.tilt_degrees >= MIN_TILT_DEGREES
    rotation = rotation_to_z(up.up if levelled else gravity.AXES[up.axis])
    colour = decide_colour(scan.rgb, params.colour)
    work = ((scan.xyz - centre) @ rotation.T) * units.metres
    stray = find_strays(work) if params.strays else np.zeros(len(scan), dtype=bool)
    identity = bool(up.axis == "+z" and not levelled and units.metres == 1.0)
    if up.confidence < UNSURE:
        warnings.append(
            f"up axis unsure ({up.axis}, confidence {up.confidence:.2f}): check the labels, "
            "or set it with --up"
        )
    if not MIN_PLAUSIBLE_M <= height <= MAX_PLAUSIBLE_M:
        warnings.append(
            f"the scan is {height:.3g} m tall in {units.unit}: no indoor scan is; check --units"
        )
    elif units.confidence < UNSURE:
        warnings.append(
            f"units unsure ({units.unit}, confidence {units.confidence:.2f}): set them with --units"
        )
    frame = Frame(
        rotation=np.eye(3) if identity else rotation,
        metres=1.0 if identity else units.metres,
        origin=np.zeros(3) if identity else centre,
        stray=stray,
        colour=colour,
        up=up,
        up_how=how,
        units=units,
        levelled=levelled,
        identity=identity,
        warnings=warnings,
    )
    for w in warnings:
        log.warning("%s", w)
    log.info("%s", frame.summary())
    return frame


def _given(
    sample: gravity.FrameSample, axis_name: str, level: bool, *, confidence: float
) -> gravity.UpEstimate:
    """Up along the signed file axis ``axis_name``, levelled by the floor's normals."""
    axis = "xyz".index(axis_name[1])
    direction = sample.directions[axis] if level else np.eye(3)[axis]
    direction = direction * np.sign(direction[axis]) * (1 if axis_name[0] == "+" else -1)
    tilt = float(np.degrees(np.arccos(np.clip(abs(direction[axis]), -1, 1))))
    return gravity.UpEstimate(direction, axis_name, tilt, confidence, {axis_name: confidence})


def _units(
    scan: Scan, params: FrameParams, sample: gravity.FrameSample, axis: int
) -> UnitsDecision:
    if params.units != "auto":
        return UnitsDecision(params.units, UNITS[params.units], "set by the user", 1.0)
    declared = scan.meta.get("units")
    if declared in UNITS:
        return UnitsDecision(declared, UNITS[declared], str(scan.meta.get("units_source")), 1.0)
    if scan.source_format == "e57":
        return UnitsDecision("m", 1.0, "E57 (metres by definition)", 1.0)
    return units_from_scale(sample.extent(sample.directions[axis]))


def work_scan(scan: Scan, frame: Frame) -> tuple[Scan, np.ndarray | None]:
    """The scan the network and the geometry see, and, when strays were set aside, the
    index of each original point's stand-in among the work scan's points (None: one to one)."""
    rgb = scan.rgb
    if not frame.colour.usable:
        rgb = None
    elif frame.colour.gains is not None and rgb is not None:
        rgb = apply_gains(rgb, frame.colour.gains)
    keep = ~frame.stray
    if frame.identity and rgb is scan.rgb and keep.all():
        return scan, None
    xyz = frame.to_work(scan.xyz)
    work = Scan(
        xyz=xyz[keep],
        rgb=None if rgb is None else rgb[keep],
        labels=None if scan.labels is None else scan.labels[keep],
        source_format=scan.source_format,
    )
    if keep.all():
        return work, None
    if not keep.any():
        raise ConfigError("every point of the scan looks stray: nothing to label")
    index = np.empty(len(scan), dtype=np.int64)
    index[keep] = np.arange(int(keep.sum()))
    _, nearest = cKDTree(work.xyz).query(xyz[~keep], workers=-1)
    index[~keep] = nearest
    return work, index
