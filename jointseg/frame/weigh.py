"""Weigh every piece of evidence on which way is up into one decision and one confidence.

Each of the six signed file axes is a candidate with a feature vector (:func:`features`): the
file's own prior (:mod:`jointseg.frame.sources`), the scan's geometry (the fitted model of
:mod:`jointseg.frame.gravity`, counted apart for room-like scans and for single views or
slices, whose extremes are not floor and ceiling), the camera convention of a single view
(:mod:`jointseg.frame.capture`) and, for the few most likely candidates, the network's verdict
(:mod:`jointseg.frame.judge`). A conditional logit over the candidates, fitted by `jointseg fit
up-axis` (:mod:`jointseg.fitting.up_axis`) on tuning scans, turns them into probabilities; the
decision's confidence is its probability, so a threshold on it means a share of right
decisions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.frame import judge
from jointseg.frame.model import MODEL_FILE, read_up_model, shipped_up_model, weight_vector
from jointseg.frame.sources import SIGNED_AXES, STRONG

#: Feature names of one candidate; the network's come last and exist only for judged ones. The
#: geometry's axis step and sign step count apart (the sign is the less sure of the two), and
#: apart for room-like scans and for single views or slices.
BASE_FEATURES: tuple[str, ...] = (
    "file",
    "axis_room",
    "sign_room",
    "axis_view",
    "sign_view",
    "camera",
    "upside_down",
)
FULL_FEATURES: tuple[str, ...] = BASE_FEATURES + tuple(f"net_{f}" for f in judge.FEATURES)
#: Candidates the network judges.
JUDGED = 2
#: The network is not asked when the evidence before it already agrees with the file's own
#: axis at least this surely: on the bench's 550 cases, asking it changed none of the 279
#: such decisions (``bench/up_axis.py``), and it costs most of the stage's time.
SURE_WITHOUT_NETWORK = 0.98
#: A file's own axis (its format's, its writer's, or a plain file's z up) is kept unless another
#: axis is at least this probable; an upside-down reading of it needs :data:`KEEP_UPSIDE_DOWN`.
#: Turning a scan that arrived right is worse than not turning one that arrived wrong, and is
#: never silent (``decide.up_warnings``). On the calibration bench's tuning deliveries
#: (``bench/frame_calibration.py``) no other axis of a file whose own axis was right reached
#: 0.27, and every right turn was at least 0.99: 0.9 asks for overwhelming evidence.
KEEP, KEEP_UPSIDE_DOWN = 0.9, 0.95
#: ... while the file's own axis is itself at least this probable (not when all else rules it out).
KEEP_FLOOR = 0.2
#: The geometry's probabilities are floored here: a fitted model sure of a wrong axis (a narrow,
#: tall room taken as lying on its side) must not outvote everything else.
MIN_P = 0.02


def fitted_weights(path: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The fitted weights without the network (``base``) and with it (``full``): the shipped
    model's (read once per process) unless ``path`` names another file.

    A model that is missing, or was fitted on other features than :data:`FULL_FEATURES`, is a
    ConfigError naming the file: placeholder weights would decide up by chance, silently.
    """
    body = shipped_up_model() if path is None else read_up_model(path)
    where = MODEL_FILE if path is None else Path(path)
    fitted = body.get("weigh")
    if not isinstance(fitted, dict) or fitted.get("features") != list(FULL_FEATURES):
        found = fitted.get("features") if isinstance(fitted, dict) else None
        raise ConfigError(
            f"the up-axis model {where} weighs the features {found}, not {list(FULL_FEATURES)}; "
            "refit it with `jointseg fit up-axis --plan fit/up_axis.json`"
        )
    base = weight_vector(fitted, "base", len(BASE_FEATURES), where)
    return base, weight_vector(fitted, "full", len(FULL_FEATURES), where)


@dataclass(frozen=True)
class Evidence:
    """The evidence on up before the network.

    Attributes
    ----------
    file : ndarray of shape (6,)
        The file's log-prior per signed axis (:data:`SIGNED_AXES`).
    axis_p, sign_p : ndarray of shape (3,)
        The geometry's probability that file axis i is the vertical one, and that +i rather
        than -i is up.
    room_like : bool
        A scan of a room (tall enough, not one camera's view).
    camera_up : str, optional
        The up of a single camera view by its convention.
    floor_only : ndarray of shape (6,), optional
        Per signed axis, the share of the scan facing along it at its low end less at its high
        end (:func:`jointseg.frame.gravity.floor_only`): a floor with no ceiling over it.
    """

    file: np.ndarray
    axis_p: np.ndarray
    sign_p: np.ndarray
    room_like: bool
    camera_up: str | None
    floor_only: np.ndarray | None = None

    @property
    def file_axis(self) -> str | None:
        """The axis the delivery itself says is up: the file's (its format's or writer's, or a
        plain file's z), except that a single camera view in a plain file is in the camera's
        frame, whose convention says up; None when neither says anything."""
        best = int(np.argmax(self.file))
        if self.file[best] <= 0:
            return self.camera_up
        if self.camera_up is not None and self.file[best] < STRONG:
            return self.camera_up
        return SIGNED_AXES[best]

    @property
    def geometry(self) -> np.ndarray:
        """(6,): the geometry's probability of each signed axis."""
        return _signed(self.axis_p) * _signs(self.sign_p)

    def base(self) -> np.ndarray:
        """(6, len(BASE_FEATURES)) features of the six candidates."""
        axis = np.log(np.clip(_signed(self.axis_p), MIN_P, 1.0))
        sign = np.log(np.clip(_signs(self.sign_p), MIN_P, 1.0))
        zero = np.zeros(6)
        camera = np.array([float(a == self.camera_up) for a in SIGNED_AXES])
        upside = np.array([float(a == "-z") for a in SIGNED_AXES])
        room = (axis, sign, zero, zero) if self.room_like else (zero, zero, axis, sign)
        return np.column_stack([self.file, *room, camera, upside])


def _signed(per_axis: np.ndarray) -> np.ndarray:
    """(3,) per file axis to (6,) per signed axis, each value twice."""
    return np.repeat(np.asarray(per_axis, dtype=np.float64), 2)


def _signs(sign_p: np.ndarray) -> np.ndarray:
    """(3,) probabilities of +i to (6,) of +i and -i."""
    p = np.empty(6)
    p[0::2] = sign_p
    p[1::2] = 1.0 - np.asarray(sign_p)
    return p


def softmax(z: np.ndarray) -> np.ndarray:
    """Probabilities from scores; -inf scores get 0."""
    finite = np.isfinite(z)
    out = np.zeros_like(z, dtype=np.float64)
    if not finite.any():
        return np.full_like(z, 1.0 / len(z), dtype=np.float64)
    e = np.exp(z[finite] - z[finite].max())
    out[finite] = e / e.sum()
    return out


@dataclass(frozen=True)
class Weighed:
    """The probabilities of the six candidates and what went into them."""

    p: np.ndarray
    base_p: np.ndarray
    judged: dict[str, np.ndarray]

    file_axis: str | None = None
    #: (6,) the geometry's own probability of each signed axis
    geometry: np.ndarray | None = None
    #: (6,) :attr:`Evidence.floor_only`; None for a single camera view, whose nearest wall is
    #: one-sided by nature
    floor_only: np.ndarray | None = None

    @property
    def floor_elsewhere(self) -> str | None:
        """The signed axis along which the scan has a floor and nothing over it (at least
        :data:`FLOOR_ONLY` of it), when that is not the axis decided; else None."""
        if self.floor_only is None:
            return None
        i = int(np.argmax(self.floor_only))
        if self.floor_only[i] < FLOOR_ONLY or SIGNED_AXES[i] == self.best:
            return None
        return SIGNED_AXES[i]

    @property
    def best(self) -> str:
        """The most probable axis, unless it overturns the file's own axis on too little."""
        return choose(self.p, self.file_axis)

    @property
    def turned(self) -> bool:
        """Whether the decision turns the scan away from the axis its file says."""
        return self.file_axis is not None and self.best != self.file_axis

    @property
    def probability(self) -> float:
        """The logit's probability of the decision (before calibration)."""
        return float(self.p[SIGNED_AXES.index(self.best)])

    @property
    def confidence(self) -> float:
        """The decision's calibrated confidence (:func:`calibrated`)."""
        return calibrated(self)

    def report(self) -> dict[str, Any]:
        """The ``frame.up.evidence`` probabilities for report.json."""

        def rounded(p: np.ndarray) -> dict[str, float]:
            return {a: round(float(v), 4) for a, v in zip(SIGNED_AXES, p, strict=True)}

        return {
            "floor_elsewhere": self.floor_elsewhere,
            "before_network": rounded(self.base_p),
            "network": {
                a: dict(zip(judge.FEATURES, np.round(f, 3).tolist(), strict=True))
                for a, f in self.judged.items()
            },
            "probabilities": rounded(self.p),
        }


def choose(p: np.ndarray, file_axis: str | None) -> str:
    """The decision from the candidates' probabilities ``p``: the most probable, but the file's
    own axis wins unless the other is at least :data:`KEEP` probable (its opposite at least
    :data:`KEEP_UPSIDE_DOWN`)."""
    best = SIGNED_AXES[int(np.argmax(p))]
    if file_axis is None or best == file_axis or p[SIGNED_AXES.index(file_axis)] < KEEP_FLOOR:
        return best
    opposite = best[1] == file_axis[1]
    needed = KEEP_UPSIDE_DOWN if opposite else KEEP
    return best if p.max() >= needed else file_axis


#: A decision the network did not check is stated unsure (at most :data:`UNCHECKED_CAP`)
#: unless the geometry alone gives its axis at least this probability. On the calibration
#: bench's rooms (``bench/frame_calibration.py``) the logit was surest of its wrong calls when
#: an upside-down S3DIS room agreed with the file's plain z on a geometry only 0.59-0.88 sure
#: of it, the network not asked; a clean synthetic 1 M-point room's geometry gives its +z 0.949.
SURE_GEOMETRY = 0.9
#: ... below the frame stage's warning threshold (``decide.UP_UNSURE``).
UNCHECKED_CAP = 0.5


#: A decision that leaves a floor without a ceiling along another axis unexplained is stated no
#: surer than this. On the calibration bench's tuning deliveries (``bench/frame_calibration.py``,
#: camera views aside) 13 of the 20 decisions so placed were right (0.65), against 0.93 of all;
#: a sideways reading of a narrow room with no ceiling (two long walls as floor and ceiling)
#: is what it catches.
FLOOR_ELSEWHERE_CAP = 0.65
#: ... when that floor is at least this share of the scan: on the tuning deliveries, the
#: lowest share at which at most 3 of the 52 right decisions stated sure (6 %) lose it.
FLOOR_ONLY = 0.08


def calibrated(w: Weighed) -> float:
    """The confidence stated for ``w``'s decision: its probability, but no more than
    :data:`FLOOR_ELSEWHERE_CAP` when a floor without a ceiling faces another axis, and no more
    than :data:`UNCHECKED_CAP` when neither the network nor a sure geometry backs it (simple
    rules, not a fit: too few wrong calls to fit one on)."""
    p = w.probability
    if w.floor_elsewhere is not None:
        p = min(p, FLOOR_ELSEWHERE_CAP)
    if w.judged or w.geometry is None:
        return p
    if float(w.geometry[SIGNED_AXES.index(w.best)]) >= SURE_GEOMETRY:
        return p
    return min(p, UNCHECKED_CAP)


def _base_p(evidence: Evidence, base_weights: np.ndarray | None) -> np.ndarray:
    weights = fitted_weights()[0] if base_weights is None else base_weights
    return softmax(evidence.base() @ weights)


def needs_judge(evidence: Evidence, base_weights: np.ndarray | None = None) -> bool:
    """Whether the network should judge: unless the evidence before it agrees with the file's
    own axis at least :data:`SURE_WITHOUT_NETWORK` surely."""
    p = _base_p(evidence, base_weights)
    best = SIGNED_AXES[int(np.argmax(p))]
    return not (best == evidence.file_axis and p.max() >= SURE_WITHOUT_NETWORK)


def candidates(
    evidence: Evidence, k: int = JUDGED, base_weights: np.ndarray | None = None
) -> list[str]:
    """The ``k`` most likely signed axes before the network."""
    base_p = _base_p(evidence, base_weights)
    return [SIGNED_AXES[i] for i in np.argsort(-base_p, kind="stable")[:k]]


def weigh(
    evidence: Evidence,
    judged: dict[str, np.ndarray] | None = None,
    *,
    base_weights: np.ndarray | None = None,
    full_weights: np.ndarray | None = None,
) -> Weighed:
    """The candidates' probabilities: the base model alone, or the full model over the judged
    candidates when the network judged some (weights: the fitted ones unless given, as the
    bench gives its own while it fits)."""
    base = evidence.base()
    base_p = _base_p(evidence, base_weights)
    file_axis = evidence.file_axis
    floor_only = evidence.floor_only if evidence.camera_up is None else None
    if not judged:
        return Weighed(base_p, base_p, {}, file_axis, evidence.geometry, floor_only)
    weights = fitted_weights()[1] if full_weights is None else full_weights
    z = np.full(6, -np.inf)
    for name, feats in judged.items():
        i = SIGNED_AXES.index(name)
        z[i] = np.concatenate([base[i], feats]) @ weights
    return Weighed(softmax(z), base_p, dict(judged), file_axis, evidence.geometry, floor_only)
