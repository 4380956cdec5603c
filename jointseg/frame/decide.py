"""The frame stage: decide once, from the scan and its file, how to put it into the frame the
network and the geometry expect (z up and level, metres, stray points aside, colour as trained
on); then run the method there and carry every per-point result back to the user's points.

The stage only decides a transform. The user's own coordinates are never changed: outputs are
the input scan plus fields, so they stay bit-exact.
"""

from __future__ import annotations

import logging
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from jointseg.exceptions import ConfigError
from jointseg.frame import gravity, weigh
from jointseg.frame.capture import Capture, capture_kind
from jointseg.frame.colour import ColourDecision, apply_gains, decide_colour
from jointseg.frame.judge import judge_frames
from jointseg.frame.params import FrameParams
from jointseg.frame.sources import SIGNED_AXES, FileEvidence, file_evidence
from jointseg.frame.strays import strays_of_columns, work_columns
from jointseg.frame.units import UnitsDecision, units_from_scale
from jointseg.io.units import UNITS
from jointseg.labeller import LabelFn
from jointseg.scan import Scan

log = logging.getLogger(__name__)

#: Tilts below this (degrees) are left alone: levelling a level scan would only move its labels.
MIN_TILT_DEGREES = 1.0
#: A scan less tall than this (m) along the up found is a slice or fragment, not a room: the
#: geometry's room-shaped evidence (floor and ceiling at the extremes) counts less.
MIN_ROOM_HEIGHT_M = 1.5
#: Heights (m) along up outside this range are no building's: the units must be wrong.
MIN_PLAUSIBLE_M, MAX_PLAUSIBLE_M = 0.05, 200.0
#: Decisions less sure than this are reported as warnings.
UNSURE = 0.6
#: An up axis stated less sure than this is reported as a warning naming ``--up``: the lowest
#: threshold above which 98 % of the tuning rooms' decisions were right, every delivery of
#: them through the stage as the pipeline runs it (``bench/frame_calibration.py``, 125
#: decisions of 12 rooms: 60 of 61 right at 0.92 and above; 75 of 79 at 0.8, 78 of 82 at
#: the 0.7 chosen before the confidence was capped by ``weigh.calibrated``).
UP_UNSURE = 0.92


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
    evidence: dict[str, Any] = field(default_factory=dict)
    #: The up the file itself says (its format's, writer's or camera's; a plain file's z);
    #: None when the user set up.
    file_axis: str | None = None

    @property
    def turned(self) -> bool:
        """Whether the stage turned the scan away from its file's own up."""
        return self.file_axis is not None and self.up.axis != self.file_axis

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
                "file_axis": self.file_axis,
                "turned": self.turned,
                "evidence": self.evidence,
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


def up_warnings(
    up: gravity.UpEstimate, file_axis: str | None, floor_elsewhere: str | None = None
) -> list[str]:
    """The warnings on a decided up: always one when it turns the scan away from the axis its
    file says (``file_axis``), naming both, the confidence and how to undo it, since a scan
    turned wrongly is labelled upside down or on its side; else one when it is unsure, naming
    the axis of a floor without a ceiling (``floor_elsewhere``) when that is why."""
    if file_axis is not None and up.axis != file_axis:
        unsure = "unsure, " if up.confidence < UP_UNSURE else ""
        return [
            f"up turned from the file's {file_axis} to {up.axis} ({unsure}confidence "
            f"{up.confidence:.2f}): if the file was right, set it back with --up {file_axis} "
            f'(in the service, rerun the job with the frame correction {{"up": "{file_axis}"}})'
        ]
    if up.confidence < UP_UNSURE:
        why = (
            f"the scan has a floor with nothing over it facing {floor_elsewhere}; if that is "
            f"up, set it with --up {floor_elsewhere}"
            if floor_elsewhere is not None
            else "check the labels, or set it with --up"
        )
        return [f"up axis unsure ({up.axis}, confidence {up.confidence:.2f}): {why}"]
    return []


def decide_frame(
    scan: Scan, params: FrameParams | None = None, judge: LabelFn | None = None
) -> Frame:
    """Decide up, tilt, units, stray points and colour for ``scan``.

    Parameters
    ----------
    scan : Scan
        With its file's format and metadata (``source_format``, ``meta``), which are evidence.
    params : FrameParams, optional
    judge : LabelFn, optional
        The network, to judge the most likely up axes by its labels
        (:func:`jointseg.network.judge.crop_labeller`); without it the decision weighs the
        file and the geometry only.

    Raises
    ------
    ConfigError
        For a scan too small or too flat to place (fewer than 20 distinct voxels).
    """
    params = params or FrameParams()
    rng = np.random.default_rng(0)
    step = max(1, len(scan) // 100_000)
    centre = np.array([np.median(scan.xyz[::step, a]) for a in range(3)])  # = along axis 0
    sample = gravity.frame_sample(scan.xyz, rng, centre=centre)
    colour = decide_colour(scan.rgb, params.colour)
    warnings: list[str] = []
    ahead = StraysAhead(scan, centre, params.strays)
    file_axis: str | None = None
    if params.up == "auto":
        up, how, evidence = decide_up(scan, sample, centre, params, colour, judge, ahead)
        gravity_aligned = bool(evidence["file"]["gravity_aligned"])
        file_axis = evidence["file_axis"]
        warnings += up_warnings(up, file_axis, evidence.get("floor_elsewhere"))
    else:
        up = _given(sample, params.up, params.level, confidence=1.0)
        how, evidence, gravity_aligned = "set by the user", {}, False
    axis = "xyz".index(up.axis[1])
    units = _units(scan, params, sample, axis)
    height = sample.extent(sample.directions[axis]) * units.metres
    levelled, rotation = placement(up, params.level, gravity_aligned)
    stray = ahead.result(rotation, units.metres)
    identity = bool(up.axis == "+z" and not levelled and units.metres == 1.0)
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
        evidence=evidence,
        file_axis=file_axis,
    )
    for w in warnings:
        log.warning("%s", w)
    log.info("%s", frame.summary())
    return frame


@dataclass(frozen=True)
class Gathered:
    """The evidence on up before the network, and what judging a candidate needs."""

    said: FileEvidence
    capture: Capture
    evidence: weigh.Evidence
    directions: dict[str, np.ndarray]
    units: list[UnitsDecision]


def gather(
    scan: Scan,
    sample: gravity.FrameSample,
    params: FrameParams,
    geometry: tuple[np.ndarray, np.ndarray] | None = None,
) -> Gathered:
    """The file's word, the kind of capture and the geometry, per signed axis; ``geometry``:
    the axis and sign steps' weights, the shipped model's unless given (a fit of the weighing
    over another model's steps)."""
    said = file_evidence(scan)
    capture = capture_kind(scan.xyz)
    units = [_units(scan, params, sample, i) for i in range(3)]
    axis_w, sign_w = gravity.model_weights() if geometry is None else geometry
    axis_p = gravity.axis_probabilities(sample, axis_w)
    sign_p = np.array(
        [gravity.sign_probability(sample, i, units[i].metres, sign_w) for i in range(3)]
    )
    top = int(np.argmax(axis_p))
    tall = sample.extent(sample.directions[top]) * units[top].metres >= MIN_ROOM_HEIGHT_M
    evidence = weigh.Evidence(
        file=said.prior,
        axis_p=axis_p,
        sign_p=sign_p,
        room_like=bool(tall and capture.kind == "scan"),
        camera_up=capture.camera_up or ("-y" if said.camera else None),
        floor_only=gravity.floor_only(sample),
    )
    directions = {
        a: _direction(sample, a, level=params.level and not said.gravity_aligned)
        for a in SIGNED_AXES
    }
    return Gathered(said, capture, evidence, directions, units)


def judge_candidates(
    gathered: Gathered,
    scan: Scan,
    centre: np.ndarray,
    colour: ColourDecision,
    judge: LabelFn,
    names: list[str],
) -> dict[str, np.ndarray]:
    """The network's features of each candidate in ``names`` (each in its own units)."""
    units = gathered.units
    base = units["xyz".index(names[0][1])].metres
    rotations = {
        a: rotation_to_z(gathered.directions[a]) * (units["xyz".index(a[1])].metres / base)
        for a in names
    }
    return judge_frames(judge, (scan.xyz - centre) * base, work_colour(scan, colour), rotations)


class StraysAhead:
    """The stray points of the work scan, found in a thread while the network judges (both
    release the GIL in their heavy parts) for the frame the evidence before it favours; used
    when the decision lands there, found again when it does not."""

    def __init__(self, scan: Scan, centre: np.ndarray, enabled: bool) -> None:
        self.scan, self.centre, self.enabled = scan, centre, enabled
        self.key: tuple[bytes, float] | None = None
        self.pool: ThreadPoolExecutor | None = None
        self.future: Future[np.ndarray] | None = None

    def _find(self, rotation: np.ndarray, metres: float) -> np.ndarray:
        xyz = self.scan.xyz
        if len(xyz) < 100:
            return np.zeros(len(xyz), dtype=bool)
        return strays_of_columns(work_columns(xyz, self.centre, rotation, metres))

    def start(self, rotation: np.ndarray, metres: float) -> None:
        """Start finding the strays of the frame ``rotation`` (file axes to work) and scale."""
        if not self.enabled:
            return
        self.key = (np.round(rotation, 12).tobytes(), metres)
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="strays")
        self.future = self.pool.submit(self._find, rotation, metres)

    def result(self, rotation: np.ndarray, metres: float) -> np.ndarray:
        """The stray mask in the frame decided (all False when strays are not set aside)."""
        if not self.enabled:
            return np.zeros(len(self.scan), dtype=bool)
        ahead = None
        if self.future is not None and self.pool is not None:
            ahead = self.future.result()
            self.pool.shutdown()
        if ahead is not None and self.key == (np.round(rotation, 12).tobytes(), metres):
            return ahead
        return self._find(rotation, metres)


def placement(
    up: gravity.UpEstimate, level: bool, gravity_aligned: bool
) -> tuple[bool, np.ndarray]:
    """Whether the scan is levelled, and the rotation taking the file's axes to z up."""
    levelled = level and up.tilt_degrees >= MIN_TILT_DEGREES and not gravity_aligned
    return levelled, rotation_to_z(up.up if levelled else gravity.AXES[up.axis])


def _estimate(g: Gathered, name: str, p: np.ndarray, confidence: float) -> gravity.UpEstimate:
    up = g.directions[name]
    tilt = float(np.degrees(np.arccos(np.clip(abs(up["xyz".index(name[1])]), -1.0, 1.0))))
    scores = dict(zip(SIGNED_AXES, np.round(p, 4).tolist(), strict=True))
    return gravity.UpEstimate(up, name, tilt, confidence, scores)


def decide_up(
    scan: Scan,
    sample: gravity.FrameSample,
    centre: np.ndarray,
    params: FrameParams,
    colour: ColourDecision,
    judge: LabelFn | None,
    ahead: StraysAhead | None = None,
) -> tuple[gravity.UpEstimate, str, dict[str, Any]]:
    """Weigh the file's word, the kind of capture, the geometry and the network's verdict on
    the most likely candidates (see :mod:`jointseg.frame.weigh`); ``ahead`` starts on the
    stray points of the frame favoured before the network while the network judges."""
    g = gather(scan, sample, params)
    judged: dict[str, np.ndarray] = {}
    asked = judge is not None and weigh.needs_judge(g.evidence)
    if judge is not None and asked:  # (judge named again for the type checker)
        if ahead is not None:
            before = weigh.weigh(g.evidence)
            guess = _estimate(g, before.best, before.p, before.confidence)
            _, rotation = placement(guess, params.level, g.said.gravity_aligned)
            ahead.start(rotation, g.units["xyz".index(guess.axis[1])].metres)
        judged = judge_candidates(g, scan, centre, colour, judge, weigh.candidates(g.evidence))
    result = weigh.weigh(g.evidence, judged)
    name = result.best
    estimate = _estimate(g, name, result.p, result.confidence)  # calibrated
    used = ["the file", "the geometry"] + (["the network"] if judged else [])
    if judge is not None and not asked:
        used.append("agreeing: the network not asked")
    how = f"weighed: {', '.join(used)} ({'; '.join(g.said.says)}; {g.capture.kind})"
    report = {
        "file": g.said.report(),
        "capture": g.capture.report(),
        "room_like": g.evidence.room_like,
        "network_asked": bool(judged),
        "file_axis": result.file_axis,
        "turned": result.turned,
        "geometry": dict(zip(SIGNED_AXES, np.round(g.evidence.geometry, 4).tolist(), strict=True)),
        **result.report(),
    }
    return estimate, how, report


def _direction(sample: gravity.FrameSample, name: str, *, level: bool) -> np.ndarray:
    """The up direction of candidate ``name``: the file axis, or the refined direction near it
    when levelling is allowed and the tilt is real (:func:`gravity.real_tilt`)."""
    axis = "xyz".index(name[1])
    sign = 1.0 if name[0] == "+" else -1.0
    if not level or not gravity.real_tilt(sample, axis):
        return gravity.AXES[name].copy()
    d = sample.directions[axis]
    return d * np.sign(d[axis]) * sign


def _given(
    sample: gravity.FrameSample, axis_name: str, level: bool, *, confidence: float
) -> gravity.UpEstimate:
    """Up along the signed file axis ``axis_name``, levelled by the floor's normals where the
    tilt is real (the same rule as a decided axis, so ``--up +z`` on a z-up scan changes
    nothing that ``auto`` would not)."""
    axis = "xyz".index(axis_name[1])
    direction = _direction(sample, axis_name, level=level)
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


def work_colour(scan: Scan, colour: ColourDecision) -> np.ndarray | None:
    """The colour the network sees: none when it is unusable, corrected when it has gains
    (``scan.rgb`` itself when neither)."""
    if not colour.usable or scan.rgb is None:
        return None
    return scan.rgb if colour.gains is None else apply_gains(scan.rgb, colour.gains)


def work_scan(scan: Scan, frame: Frame) -> tuple[Scan, np.ndarray | None]:
    """The scan the network and the geometry see, and, when strays were set aside, the
    index of each original point's stand-in among the work scan's points (None: one to one)."""
    rgb = work_colour(scan, frame.colour)
    keep = ~frame.stray
    if frame.identity and rgb is scan.rgb and keep.all():
        return scan, None
    xyz = frame.to_work(scan.xyz)
    work = Scan(  # np.compress: the rows of xyz[keep], without boolean indexing's slow path
        xyz=np.compress(keep, xyz, axis=0),
        rgb=None if rgb is None else np.compress(keep, rgb, axis=0),
        labels=None if scan.labels is None else np.compress(keep, scan.labels),
        source_format=scan.source_format,
    )
    if keep.all():
        return work, None
    if not keep.any():
        raise ConfigError("every point of the scan looks stray: nothing to label")
    index = np.empty(len(scan), dtype=np.int64)
    index[keep] = np.arange(int(keep.sum()))
    index[~keep] = nearest_kept(work.xyz, xyz[~keep])
    return work, index


#: Strays are matched to kept points through a tree of candidates only when they are fewer than
#: this share of the kept points, on a scan of at least :data:`NEAR_MIN_POINTS` ...
NEAR_MAX_SHARE = 1 / 64
NEAR_MIN_POINTS = 50_000
#: ... from an upper bound on each one's distance given by every this many kept points ...
NEAR_STEP = 32
#: ... on a grid of at most this many cells along the scan's longest side.
NEAR_CELLS = 128


def nearest_kept(kept: np.ndarray, strays: np.ndarray) -> np.ndarray:
    """The index of each stray point's nearest kept point, as a k-d tree of all the kept points
    answers (``cKDTree(kept).query``), without building that tree over a big scan.

    A tree of every :data:`NEAR_STEP`-th kept point bounds each stray's distance; only the
    kept points in grid cells within that bound of some stray can be nearest, and a tree of
    them answers. Where two of them lie (nearly) as near as each other the full tree's own
    choice among them is kept: it is asked instead.
    """
    n = len(kept)
    if n < NEAR_MIN_POINTS or len(strays) > NEAR_MAX_SHARE * n:
        return _full_tree_nearest(kept, strays)
    bound, _ = cKDTree(kept[::NEAR_STEP]).query(strays, workers=-1)
    bound = bound * (1.0 + 1e-9) + 1e-9
    lo = kept.min(axis=0)
    cell = max(float(np.max(kept.max(axis=0) - lo)) / NEAR_CELLS, 1e-9)
    dims = np.floor((kept.max(axis=0) - lo) / cell).astype(np.int64) + 1
    # the cells each stray's box of half-width ``bound`` overlaps, marked through a difference
    # array (+1 and -1 at the box's corners, summed up along the three axes)
    first = np.clip(np.floor((strays - bound[:, None] - lo) / cell).astype(np.int64), 0, dims)
    last = np.clip(np.floor((strays + bound[:, None] - lo) / cell).astype(np.int64) + 1, 0, dims)
    marks = np.zeros(tuple(dims + 1), dtype=np.int32)
    for corner in range(8):
        ends = [last if corner >> a & 1 else first for a in range(3)]
        sign = -1 if bin(corner).count("1") % 2 else 1
        np.add.at(marks, (ends[0][:, 0], ends[1][:, 1], ends[2][:, 2]), sign)
    marked = np.cumsum(np.cumsum(np.cumsum(marks, 0), 1), 2)[:-1, :-1, :-1] > 0
    ij = [
        np.minimum(np.floor((kept[:, a] - lo[a]) / cell).astype(np.int64), dims[a] - 1)
        for a in range(3)
    ]
    candidates = np.flatnonzero(marked[ij[0], ij[1], ij[2]])
    if len(candidates) > n // 2:
        return _full_tree_nearest(kept, strays)
    distance, found = cKDTree(kept[candidates]).query(strays, k=2, workers=-1)
    if not np.all(distance[:, 1] - distance[:, 0] > 1e-9 * distance[:, 0] + 1e-12):
        return _full_tree_nearest(kept, strays)
    return candidates[found[:, 0]]


def _full_tree_nearest(kept: np.ndarray, strays: np.ndarray) -> np.ndarray:
    _, nearest = cKDTree(kept).query(strays, workers=-1)
    return np.asarray(nearest, dtype=np.int64)
