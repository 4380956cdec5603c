"""Which way is up: the scan's own evidence of gravity.

Indoor scans are built of planes at right angles (floors, ceilings, walls), so the normals of a
scan cluster around three orthogonal directions (a Manhattan frame), each within a few degrees
of one of the file's axes for any scan that was delivered with an axis up (tilts of up to
:data:`MAX_TILT_DEGREES` are searched). The geometry's evidence on which of the three is up,
and its sign, comes in two steps, each a logistic score of a few features fitted on tuning
rooms; :mod:`jointseg.frame.weigh` weighs them with the file's word and the network's:

- the axis: the vertical one is the one whose facing points (floor, ceiling) sit at the two
  extremes of its extent rather than inside it, and along which the scan is shortest;
- the sign: furniture stands on the floor, so the bulk of what is inside the room, and the
  flat tops of seats and desks (0.3-1.1 m up), gather at the floor's end; a ceiling may be
  missing from a handheld scan, a floor hardly ever.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jointseg.frame.model import MODEL_FILE, read_up_model, shipped_up_model, weight_vector
from jointseg.geometry.alignment import estimate_normals
from jointseg.voxels import voxel_index

#: Normals within this angle of an axis count as facing along it.
FACING_DEGREES = 12.0
#: The largest tilt searched around each of the file's axes.
MAX_TILT_DEGREES = 25.0
#: Points and voxels the decision looks at: enough for a room's planes, cheap on a big scan.
SAMPLE_POINTS = 200_000
VOXELS_ACROSS = 160
#: Extreme layers: the lowest and highest share of the extent.
LAYER = 0.08

#: Height profiles: bins across the extent along a direction.
PROFILE_BINS = 10
#: Lengths of the logistic weights of the axis step and of the sign step (see
#: :func:`axis_features` and :func:`sign_features`): ``up_model.json``'s ``axis_weights`` and
#: ``sign_weights``, fitted in issue 31 on its tuning rooms (``bench/up_axis.py --fit`` at commit
#: 586b150; `jointseg fit up-axis` fits the weighing over them, ``up_model.json``'s ``weigh``,
#: and copies them; ``up_model.provenance.json`` says what is known of both).
AXIS_SIZE, SIGN_SIZE = 3 * PROFILE_BINS + 3, 3 * PROFILE_BINS + 4

AXES: dict[str, np.ndarray] = {
    "+x": np.array([1.0, 0.0, 0.0]),
    "-x": np.array([-1.0, 0.0, 0.0]),
    "+y": np.array([0.0, 1.0, 0.0]),
    "-y": np.array([0.0, -1.0, 0.0]),
    "+z": np.array([0.0, 0.0, 1.0]),
    "-z": np.array([0.0, 0.0, -1.0]),
}


@dataclass(frozen=True)
class UpEstimate:
    """The up direction found, in the file's axes, and how sure each step was.

    Attributes
    ----------
    up : ndarray of shape (3,)
        Unit vector, the scan's up in its own coordinates (tilt included).
    axis : str
        The signed file axis nearest to ``up`` ('+z', '-y', ...).
    tilt_degrees : float
        Angle between ``up`` and that axis.
    confidence : float
        0-1: the probability of the axis step times that of the sign step.
    scores : dict of str to float
        Probability of every signed axis.
    """

    up: np.ndarray
    axis: str
    tilt_degrees: float
    confidence: float
    scores: dict[str, float]


def refine_axis(normals: np.ndarray, axis: np.ndarray, *, max_degrees: float) -> np.ndarray:
    """The dominant normal direction within ``max_degrees`` of ``axis`` (sign folded to it).

    A coarse peak of the folded normals near the axis, then the mean of those within
    :data:`FACING_DEGREES` of the peak, twice: a tilted floor and ceiling pull it to the true
    up while the walls' normals, far from the axis, take no part.
    """
    dots = normals @ axis
    folded = normals * np.where(dots < 0, -1.0, 1.0)[:, None]
    near = folded[np.abs(dots) >= np.cos(np.radians(max_degrees))]
    if len(near) < 10:
        return axis
    direction = _peak_direction(near, axis, max_degrees)
    for _ in range(2):
        close = near[near @ direction >= np.cos(np.radians(FACING_DEGREES))]
        if len(close) < 10:
            break
        mean = close.sum(axis=0)
        direction = mean / np.linalg.norm(mean)
    return direction


def _peak_direction(near: np.ndarray, axis: np.ndarray, max_degrees: float) -> np.ndarray:
    """The densest 2-degree cell of the normals' projection on the plane across ``axis``."""
    u = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    a = np.degrees(np.arctan2(near @ u, near @ axis))
    b = np.degrees(np.arctan2(near @ v, near @ axis))
    bins = int(2 * max_degrees / 2.0)
    hist, ea, eb = np.histogram2d(a, b, bins=bins, range=[[-max_degrees, max_degrees]] * 2)
    i, j = np.unravel_index(np.argmax(hist), hist.shape)
    ta, tb = np.radians((ea[i] + ea[i + 1]) / 2), np.radians((eb[j] + eb[j + 1]) / 2)
    direction = axis + np.tan(ta) * u + np.tan(tb) * v
    return direction / np.linalg.norm(direction)


@dataclass(frozen=True)
class FrameSample:
    """Voxel centroids of (a sample of) the scan with their normals, and the three directions
    near the file's axes that the normals cluster around."""

    xyz: np.ndarray
    normals: np.ndarray
    directions: np.ndarray  # (3, 3): row i is the refined direction near file axis i

    def extent(self, direction: np.ndarray) -> float:
        h = self.xyz @ direction
        lo, hi = np.quantile(h, [0.005, 0.995])
        return float(hi - lo)


def frame_sample(
    xyz: np.ndarray, rng: np.random.Generator | None = None, *, centre: np.ndarray | None = None
) -> FrameSample:
    """A scale-free sample for the decisions: voxel centroids at 1/:data:`VOXELS_ACROSS` of the
    robust extent, normals from 16 neighbours; of ``xyz - centre`` when ``centre`` is given
    (only the sampled points are moved, the same values as moving all of them first)."""
    rng = rng or np.random.default_rng(0)
    pts = xyz if len(xyz) <= SAMPLE_POINTS else xyz[rng.choice(len(xyz), SAMPLE_POINTS, False)]
    if centre is not None:
        pts = pts - centre
    # each axis on its own: the quantiles along axis 0, without its strided copy
    lo, hi = np.array([np.quantile(pts[:, a], [0.005, 0.995]) for a in range(3)]).T
    voxel = max(float(np.max(hi - lo)) / VOXELS_ACROSS, 1e-9)
    _, centroids = voxel_index(pts - pts.mean(axis=0), voxel)
    if len(centroids) < 20:
        return FrameSample(centroids, np.zeros_like(centroids), np.eye(3))
    normals = estimate_normals(centroids, k=min(16, len(centroids) - 1))
    directions = np.stack(
        [refine_axis(normals, np.eye(3)[i], max_degrees=MAX_TILT_DEGREES) for i in range(3)]
    )
    return FrameSample(centroids, normals, directions)


def profile(sample: FrameSample, direction: np.ndarray) -> np.ndarray:
    """(3 * PROFILE_BINS,): the share of points in each height bin along ``direction``, for
    points facing along it, across it (walls, when it is up) and the rest."""
    t = np.clip(_normalised(sample.xyz @ direction), 0.0, 1.0 - 1e-9)
    bins = (t * PROFILE_BINS).astype(np.int64)
    c = np.abs(sample.normals @ direction)
    along = c >= np.cos(np.radians(FACING_DEGREES))
    across = c <= np.sin(np.radians(FACING_DEGREES))
    n = max(len(t), 1)
    return np.concatenate(
        [
            np.bincount(bins[g], minlength=PROFILE_BINS) / n
            for g in (along, across, ~(along | across))
        ]
    )


def _flip(profile_: np.ndarray) -> np.ndarray:
    return profile_.reshape(3, PROFILE_BINS)[:, ::-1].ravel()


def axis_features(sample: FrameSample) -> np.ndarray:
    """(3, 3 * PROFILE_BINS + 3): per file axis, its height profile folded (so the sign does
    not matter), the share of normals facing along it, the share of those inside the extreme
    layers, and the log of its extent over the other two's geometric mean."""
    ext = np.array([max(sample.extent(d), 1e-12) for d in sample.directions])
    rows = []
    for i, d in enumerate(sample.directions):
        prof = profile(sample, d)
        facing = np.abs(sample.normals @ d) >= np.cos(np.radians(FACING_DEGREES))
        t = _normalised(sample.xyz @ d)
        inside = (t > LAYER) & (t < 1 - LAYER)
        fshare = float(facing.mean())
        finter = float((facing & inside).sum() / max(facing.sum(), 1))
        others = np.delete(ext, i)
        rows.append(
            [*(prof + _flip(prof)), fshare, finter, float(np.log(ext[i] / np.sqrt(others.prod())))]
        )
    return np.array(rows)


def sign_features(sample: FrameSample, up: np.ndarray, metres_per_unit: float) -> np.ndarray:
    """(3 * PROFILE_BINS + 4,): evidence that ``up`` (rather than ``-up``) points away from
    the floor: the height profile less its mirror image, where the bulk of the room sits, the
    floor layer against the ceiling layer, flat tops 0.3-1.1 m from each end; each feature
    flips its sign with ``up``."""
    h = sample.xyz @ up
    t = _normalised(h)
    lo, hi = np.quantile(h, [0.005, 0.995])
    facing = np.abs(sample.normals @ up) >= np.cos(np.radians(FACING_DEGREES))
    inside = (t > LAYER) & (t < 1 - LAYER)
    mass = 0.5 - float(np.median(t[inside])) if inside.any() else 0.0
    low = int(np.count_nonzero(facing & (t <= LAYER)))
    high = int(np.count_nonzero(facing & (t >= 1 - LAYER)))
    floor = _balance(low, high)
    metres_low = (h - lo) * metres_per_unit
    metres_high = (hi - h) * metres_per_unit
    band_lo = facing & inside & (metres_low > 0.3) & (metres_low < 1.1)
    band_hi = facing & inside & (metres_high > 0.3) & (metres_high < 1.1)
    flat = _balance(int(band_lo.sum()), int(band_hi.sum()))
    tops = facing & inside
    tops_balance = _balance(int((tops & (t < 0.5)).sum()), int((tops & (t >= 0.5)).sum()))
    prof = profile(sample, up)
    return np.array([*(prof - _flip(prof)), mass, floor, flat, tops_balance])


#: "Nothing over it": the far end of a floor-only axis holds less than this share of what its
#: near end holds (a cluttered floor under a whole ceiling still counts as both).
NOTHING_OVER = 0.1


def floor_only(sample: FrameSample) -> np.ndarray:
    """(6,) per signed file axis (``+x, -x, +y, -y, +z, -z``): the share of the sample facing
    along it in its lowest layer less the share in its highest, where the highest holds next
    to nothing (:data:`NOTHING_OVER`), else 0. Large for the up of a room scanned without its
    ceiling (RGB-D reconstructions, phone scans: a floor, nothing over it); 0 along an axis
    with planes at both ends (walls; floor and ceiling)."""
    out = np.zeros(6)
    if len(sample.normals) == 0:
        return out
    cos = np.cos(np.radians(FACING_DEGREES))
    for i, d in enumerate(sample.directions):
        d = d if d[i] >= 0 else -d
        t = _normalised(sample.xyz @ d)
        facing = np.abs(sample.normals @ d) >= cos
        low = np.count_nonzero(facing & (t <= LAYER)) / len(t)
        high = np.count_nonzero(facing & (t >= 1 - LAYER)) / len(t)
        out[2 * i] = low - high if high <= NOTHING_OVER * low else 0.0
        out[2 * i + 1] = high - low if low <= NOTHING_OVER * high else 0.0
    return out


def _balance(a: int, b: int) -> float:
    return float((a - b) / max(a + b, 1))


def _normalised(h: np.ndarray) -> np.ndarray:
    lo, hi = np.quantile(h, [0.005, 0.995])
    return (h - lo) / max(hi - lo, 1e-12)


def _softmax(z: np.ndarray) -> np.ndarray:
    e = np.exp(z - z.max())
    return e / e.sum()


def model_weights(path: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The axis step's and the sign step's logistic weights: the shipped model's (read once per
    process) unless ``path`` names another file; a ConfigError naming the file when it is
    missing, never zeros (an installation without it would decide up by chance)."""
    body = shipped_up_model() if path is None else read_up_model(path)
    where = MODEL_FILE if path is None else Path(path)
    axis = weight_vector(body, "axis_weights", AXIS_SIZE, where)
    return axis, weight_vector(body, "sign_weights", SIGN_SIZE, where)


def axis_probabilities(sample: FrameSample, weights: np.ndarray | None = None) -> np.ndarray:
    """(3,): the geometry's probability that each file axis is the vertical one (the file's own
    evidence is weighed apart, :mod:`jointseg.frame.weigh`); ``weights``: the shipped model's
    unless given (a fit weighing another model's steps)."""
    w = model_weights()[0] if weights is None else weights
    return _softmax(axis_features(sample) @ w)


def sign_probability(
    sample: FrameSample, axis: int, metres_per_unit: float, weights: np.ndarray | None = None
) -> float:
    """The geometry's probability that +``axis`` rather than -``axis`` is up (``weights``: the
    shipped model's unless given)."""
    d = sample.directions[axis]
    d = d if d[axis] >= 0 else -d
    w = model_weights()[1] if weights is None else weights
    score = float(sign_features(sample, d, metres_per_unit) @ w)
    return float(1.0 / (1.0 + np.exp(-np.clip(score, -50.0, 50.0))))


#: Normals within this angle of a direction count as a plane facing along it.
SUPPORT_DEGREES = 5.0
#: A levelling direction must be the facing direction of at least this share of the sample.
MIN_SUPPORT = 0.03


def plane_support(sample: FrameSample, direction: np.ndarray) -> float:
    """The share of the sample's normals within :data:`SUPPORT_DEGREES` of ``±direction``:
    how much real floor and ceiling face along it."""
    if len(sample.normals) == 0:
        return 0.0
    c = np.abs(sample.normals @ (direction / np.linalg.norm(direction)))
    return float((c >= np.cos(np.radians(SUPPORT_DEGREES))).mean())


def real_tilt(sample: FrameSample, axis: int) -> bool:
    """Whether the refined direction near ``axis`` is a real tilt: planes that are really there
    face along it (at least :data:`MIN_SUPPORT` of the sample, and more than face along the
    file axis itself). A slanted roof, a ramp or a stair never tilts a level scan."""
    refined = plane_support(sample, sample.directions[axis])
    return refined >= MIN_SUPPORT and refined > plane_support(sample, np.eye(3)[axis])
