"""Weigh every piece of evidence on which way is up into one decision and one confidence.

Each of the six signed file axes is a candidate with a feature vector (:func:`features`): the
file's own prior (:mod:`jointseg.frame.sources`), the scan's geometry (the fitted model of
:mod:`jointseg.frame.gravity`, counted apart for room-like scans and for single views or
slices, whose extremes are not floor and ceiling), the camera convention of a single view
(:mod:`jointseg.frame.capture`) and, for the few most likely candidates, the network's verdict
(:mod:`jointseg.frame.judge`). A conditional logit over the candidates, fitted by
``bench/up_axis.py --fit`` on tuning scans, turns them into probabilities; the decision's
confidence is its probability, so a threshold on it means a share of right decisions.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.frame import judge
from jointseg.frame.sources import SIGNED_AXES

#: Feature names of one candidate; the network's come last and exist only for judged ones.
BASE_FEATURES: tuple[str, ...] = ("file", "geometry_room", "geometry_view", "camera")
FULL_FEATURES: tuple[str, ...] = BASE_FEATURES + tuple(f"net_{f}" for f in judge.FEATURES)
#: Candidates the network judges.
JUDGED = 3
#: Geometry log-probabilities are floored here (a certain model is never quite certain).
MIN_P = 1e-4

MODEL_FILE = Path(__file__).with_name("up_model.json")
_MODEL = json.loads(MODEL_FILE.read_text()) if MODEL_FILE.is_file() else {}
#: Fitted weights: without the network (``base``) and with it (``full``).
BASE_WEIGHTS = np.array(_MODEL.get("weigh", {}).get("base", [1.0, 1.0, 0.3, 2.0]))
FULL_WEIGHTS = np.array(
    _MODEL.get("weigh", {}).get("full", [1.0, 1.0, 0.3, 2.0, 10.0, 3.0, -3.0, 1.0, -1.0, 2.0])
)


@dataclass(frozen=True)
class Evidence:
    """Per-candidate evidence before the network (arrays over :data:`SIGNED_AXES`)."""

    file: np.ndarray
    geometry: np.ndarray  # log-probability of each signed axis from the geometry alone
    room_like: bool
    camera_up: str | None

    def base(self) -> np.ndarray:
        """(6, len(BASE_FEATURES)) features of the six candidates."""
        camera = np.array([float(a == self.camera_up) for a in SIGNED_AXES])
        room = self.geometry if self.room_like else np.zeros(6)
        view = np.zeros(6) if self.room_like else self.geometry
        return np.column_stack([self.file, room, view, camera])


def geometry_logp(axis_p: np.ndarray, sign_p: np.ndarray) -> np.ndarray:
    """Log-probability of each signed axis from the axis step's (3,) and the sign step's (3,)
    probabilities (``sign_p[i]``: +i rather than -i is up)."""
    p = np.empty(6)
    p[0::2] = axis_p * sign_p
    p[1::2] = axis_p * (1.0 - sign_p)
    return np.log(np.clip(p, MIN_P, 1.0))


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

    @property
    def best(self) -> str:
        return SIGNED_AXES[int(np.argmax(self.p))]

    @property
    def confidence(self) -> float:
        return float(self.p.max())

    def report(self) -> dict[str, Any]:
        """The ``frame.up.evidence`` probabilities for report.json."""
        def rounded(p: np.ndarray) -> dict[str, float]:
            return {a: round(float(v), 4) for a, v in zip(SIGNED_AXES, p, strict=True)}

        return {
            "before_network": rounded(self.base_p),
            "network": {
                a: dict(zip(judge.FEATURES, np.round(f, 3).tolist(), strict=True))
                for a, f in self.judged.items()
            },
            "probabilities": rounded(self.p),
        }


def candidates(evidence: Evidence, k: int = JUDGED) -> list[str]:
    """The ``k`` most likely signed axes before the network."""
    base_p = softmax(evidence.base() @ BASE_WEIGHTS)
    return [SIGNED_AXES[i] for i in np.argsort(-base_p, kind="stable")[:k]]


def weigh(evidence: Evidence, judged: dict[str, np.ndarray] | None = None) -> Weighed:
    """The candidates' probabilities: the base model alone, or the full model over the judged
    candidates when the network judged some."""
    base = evidence.base()
    base_p = softmax(base @ BASE_WEIGHTS)
    if not judged:
        return Weighed(base_p, base_p, {})
    z = np.full(6, -np.inf)
    for name, feats in judged.items():
        i = SIGNED_AXES.index(name)
        z[i] = np.concatenate([base[i], feats]) @ FULL_WEIGHTS
    return Weighed(softmax(z), base_p, dict(judged))
