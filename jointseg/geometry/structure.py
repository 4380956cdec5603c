"""The room's structure read from its own geometry (issue 43): which segments are floor,
ceiling or wall, with a confidence, using no labels at all.

The network is at home on the scans it was trained on and lost on others (phone LiDAR, RGB-D
reconstructions, depth cameras), and where it is lost the fusion vote used to follow it. The
planes that make a room, though, look alike on every sensor:

- **floor**: horizontal surfaces at the storey's lowest level (at least :data:`MIN_LEVEL_AREA`
  of them together, however many pieces they come in), or a large step above it;
- **ceiling**: large horizontal surfaces at the top of the storey, at least
  :data:`MIN_STOREY` above the floor;
- **wall**: vertical planes that span much of the storey's height (or reach its top) and bound
  the scan (few points behind them, the room above a cabinet included), or that reach the
  ceiling itself; lower vertical pieces (:data:`LOW_WALL` high) only where they bound the scan
  (an RGB-D sweep sees many walls only between the furniture and the camera's reach);
- **not structure**: everything else, among it table tops (horizontal, well between floor and
  ceiling), cabinet and bookcase faces (vertical, short, with the room's wall behind them) and
  door leaves (vertical, door-sized, not reaching a seen ceiling: without one, a wall captured
  only to door height looks the same and is far more common).

Each segment is summarised once (size, plane fit, height range, footprint), so the reading
costs a few bincounts and one sort of a sub-sample, and works on a tile as on a whole scan.
The scan must be levelled (z up, metres), as the geometry stage's input is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jointseg.classes import CLASS_INDEX
from jointseg.grouping import group_quantiles, sorted_distinct

FLOOR, CEILING, WALL = CLASS_INDEX["floor"], CLASS_INDEX["ceiling"], CLASS_INDEX["wall"]
#: A surface is horizontal (vertical) when its normal is within this of vertical (horizontal).
TILT_DEG = 12.0
#: The least height of a storey (floor to ceiling), m: higher surfaces may be ceiling.
MIN_STOREY = 2.0
#: A scan less high than this (m) holds no storey (a desk top, a floor patch).
MIN_HEIGHT = 0.5
#: The least footprint (m²) of a floor or ceiling level.
MIN_LEVEL_AREA = 1.0
#: The least footprint (m²) of one floor or ceiling segment.
MIN_SURFACE_AREA = 0.25
#: A floor segment lies this close (m) to the floor level; up to STEP above, a big one is a step.
FLOOR_BAND, STEP = 0.08, 0.3
#: A ceiling segment lies at most this far (m) below the ceiling level (a beam's underside,
#: further down, is not ceiling).
CEILING_BAND = 0.15
#: A wall spans this share of the storey's height, or reaches this close (m) to its top.
WALL_SPAN, WALL_TOP = 0.2, 0.6
#: A lower vertical piece (at least this high, m) is a wall where it bounds the scan: an RGB-D
#: sweep often sees a wall only between furniture and the camera's reach.
LOW_WALL = 0.5
#: The floor level lies at most this far (m) above the scan's lowest points.
FLOOR_REACH = 0.5
#: The least length (m) of a wall segment along the floor.
MIN_WALL_LENGTH = 0.4
#: A door leaf: at most this long (m) and this high above the floor (m), standing on the floor
#: (its bottom at most DOOR_FOOT above it: a wall seen only above the furniture is no door).
DOOR_LENGTH, DOOR_TOP, DOOR_FOOT = 1.3, 2.3, 0.15
#: The least footprint (m²) of a piece of a ceiling.
MIN_PIECE_AREA = 0.05
#: The least points of a piece of a floor or ceiling level.
MIN_PIECE_POINTS = 20
#: A piece of a wall lies this close (m) to a read wall's plane, at most PIECE_REACH (m) beyond
#: its ends, has at least WALL_PIECE_POINTS points (of the voxelised scan), and is upright and
#: parallel to the wall within PIECE_TILT_DEG: the small pieces an RGB-D reconstruction's
#: colour and noise cut a wall into are neither quite flat nor quite in its plane.
PIECE_GAP, PIECE_REACH, WALL_PIECE_POINTS, PIECE_TILT_DEG = 0.08, 1.0, 10, 25.0
#: A plane bounds the scan when, behind it, there are at most this share of the points in front.
BEHIND_SHARE = 0.08
#: The points behind a plane are counted between these distances (m).
BEHIND_NEAR, BEHIND_FAR = 0.12, 3.0
#: A segment thicker than this (m, its plane fit's standard deviation) is not a surface.
MAX_THICKNESS = 0.04
#: Side (m) of the cells that measure a surface's footprint.
AREA_CELL = 0.1
#: Points sampled for the height ranges and the behind-the-wall counts.
SAMPLE = 200_000
BEHIND_SAMPLE = 30_000


#: The least points read as floor before they set the floor level.
MIN_FLOOR_POINTS = 50


def floor_level(z: np.ndarray, kind: np.ndarray) -> float | None:
    """The floor level a structure reading gives (``kind``: per point, as
    :meth:`Structure.point_kind`): the median height of the points read as floor, or None with
    fewer than :data:`MIN_FLOOR_POINTS` (a tile or scan that shows too little floor)."""
    floor = np.asarray(z)[np.asarray(kind) == FLOOR]
    return float(np.median(floor)) if floor.size >= MIN_FLOOR_POINTS else None


@dataclass(frozen=True)
class Structure:
    """The structural reading of every segment.

    Attributes
    ----------
    kind : ndarray of shape (S,), int64
        FLOOR, CEILING or WALL (class indices), or -1 for not structure.
    confidence : ndarray of shape (S,), float64
        How sure the geometry is, in [0, 1] (0 where ``kind`` is -1).
    on_surface : ndarray of shape (N,), bool
        Points within ``tolerance`` of their segment's plane: only these take a structural
        label (a chair leg grouped with the floor does not).
    floor_z, ceiling_z : float or None
        The storey's floor and ceiling levels, m; None where the scan shows none.
    """

    kind: np.ndarray
    confidence: np.ndarray
    on_surface: np.ndarray
    floor_z: float | None
    ceiling_z: float | None

    def point_kind(self, segments: np.ndarray) -> np.ndarray:
        """Each point's structural class (-1 for none or off its segment's plane), int8."""
        return np.where(self.on_surface, self.kind[segments], -1).astype(np.int8)

    def point_confidence(self, segments: np.ndarray) -> np.ndarray:
        """Each point's reading confidence (0 for none or off its segment's plane), float32."""
        return np.where(self.on_surface, self.confidence[segments], 0.0).astype(np.float32)

    def counts(self) -> dict[str, int]:
        """Segments read as each kind, for the report."""
        return {
            name: int(np.count_nonzero(self.kind == k))
            for name, k in (("floor", FLOOR), ("ceiling", CEILING), ("wall", WALL))
        }


@dataclass(frozen=True)
class _Segments:
    """Per-segment plane fits: size, centre, unit normal, thickness, height range, length."""

    count: np.ndarray
    centre: np.ndarray
    normal: np.ndarray
    thickness: np.ndarray
    z_low: np.ndarray
    z_high: np.ndarray
    length: np.ndarray

    @property
    def horizontal(self) -> np.ndarray:
        return (np.abs(self.normal[:, 2]) >= np.cos(np.radians(TILT_DEG))) & self.flat

    @property
    def vertical(self) -> np.ndarray:
        return self.upright(TILT_DEG)

    def upright(self, tilt_deg: float) -> np.ndarray:
        """Flat segments whose normal is within ``tilt_deg`` of horizontal."""
        return (np.abs(self.normal[:, 2]) <= np.sin(np.radians(tilt_deg))) & self.flat

    @property
    def flat(self) -> np.ndarray:
        return self.thickness <= MAX_THICKNESS


def _fits(xyz: np.ndarray, seg: np.ndarray, n_seg: int) -> tuple[np.ndarray, ...]:
    """Count, centre, normal (smallest principal axis), thickness and covariance per segment."""
    count = np.bincount(seg, minlength=n_seg).astype(np.float64)
    origin = xyz.mean(axis=0)
    p = xyz - origin
    safe = np.maximum(count, 1)
    mean = np.column_stack([np.bincount(seg, p[:, i], n_seg) for i in range(3)]) / safe[:, None]
    cov = np.empty((n_seg, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = (
                np.bincount(seg, p[:, i] * p[:, j], n_seg) / safe - mean[:, i] * mean[:, j]
            )
    values, vectors = np.linalg.eigh(cov)
    normal = vectors[:, :, 0]
    thickness = np.sqrt(np.maximum(values[:, 0], 0.0))
    return count, mean + origin, normal, thickness, cov


def _summarise(xyz: np.ndarray, seg: np.ndarray, n_seg: int, rng: np.random.Generator) -> _Segments:
    count, centre, normal, thickness, cov = _fits(xyz, seg, n_seg)
    pick = rng.choice(len(xyz), SAMPLE, replace=False) if len(xyz) > SAMPLE else slice(None)
    z_low, z_high = group_quantiles(seg[pick], n_seg, xyz[pick, 2], (0.02, 0.98))
    # length along the floor, across the normal: a uniform spread of variance v spans sqrt(12 v)
    along = np.column_stack([-normal[:, 1], normal[:, 0], np.zeros(n_seg)])
    along /= np.maximum(np.linalg.norm(along, axis=1), 1e-9)[:, None]
    var = np.einsum("si,sij,sj->s", along, cov, along)
    length = np.sqrt(12.0 * np.maximum(var, 0.0))
    return _Segments(count, centre, normal, thickness, z_low, z_high, length)


def _footprints(xyz: np.ndarray, seg: np.ndarray, n_seg: int, chosen: np.ndarray) -> np.ndarray:
    """Plan area (m²) of each chosen segment: its occupied AREA_CELL cells in x, y."""
    area = np.zeros(n_seg)
    on = chosen[seg]
    if not on.any():
        return area
    cells = np.floor(xyz[on, :2] / AREA_CELL).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    key = (seg[on].astype(np.int64) * span[0] + cells[:, 0]) * span[1] + cells[:, 1]
    unique = sorted_distinct(key)
    owner = unique // (span[0] * span[1])
    return np.bincount(owner, minlength=n_seg) * AREA_CELL**2


def _level_areas(z: np.ndarray, area: np.ndarray, cand: np.ndarray) -> tuple[np.ndarray, ...]:
    """The candidates' heights (sorted), their indices, and the horizontal area of every
    candidate within FLOOR_BAND of each: a floor broken into many small pieces (a mesh's
    holes, colour changes) is still one large level."""
    order = cand[np.argsort(z[cand])]
    heights = z[order]
    total = np.concatenate([[0.0], np.cumsum(area[order])])
    left = np.searchsorted(heights, heights - FLOOR_BAND, "left")
    right = np.searchsorted(heights, heights + FLOOR_BAND, "right")
    return heights, order, total[right] - total[left]


def _floor_level(s: _Segments, area: np.ndarray, cand: np.ndarray, bottom: float) -> float | None:
    """The lowest level with MIN_LEVEL_AREA of horizontal surface, near the scan's bottom (the
    largest such level within FLOOR_BAND of the lowest), unless MIN_SURFACE_AREA of horizontal
    surface lies more than STEP under it: then the lowest such level."""
    heights, _, level = _level_areas(s.centre[:, 2], area, cand)
    ok = np.flatnonzero((level >= MIN_LEVEL_AREA) & (heights <= bottom + FLOOR_REACH))
    if len(ok) == 0:
        return None
    near = ok[heights[ok] <= heights[ok[0]] + FLOOR_BAND]
    floor_z = float(heights[near[np.argmax(level[near])]])
    # nothing sizeable lies under a floor: a level found above such a surface is furniture (a
    # camera's single view may see more table and seat tops than floor), and the floor is the
    # lowest such surface
    under = np.flatnonzero((level >= MIN_SURFACE_AREA) & (heights < floor_z - STEP))
    if len(under) == 0:
        return floor_z
    near = under[heights[under] <= heights[under[0]] + FLOOR_BAND]
    return float(heights[near[np.argmax(level[near])]])


def _ceiling_level(
    s: _Segments, area: np.ndarray, cand: np.ndarray, floor_z: float
) -> float | None:
    """The highest level with MIN_LEVEL_AREA of horizontal surface, a storey above the floor."""
    heights, _, level = _level_areas(s.centre[:, 2], area, cand)
    ok = np.flatnonzero((level >= MIN_LEVEL_AREA) & (heights >= floor_z + MIN_STOREY))
    if len(ok) == 0:
        return None
    near = ok[heights[ok] >= heights[ok[-1]] - FLOOR_BAND]
    return float(heights[near[np.argmax(level[near])]])


def _behind_shares(
    xyz: np.ndarray, s: _Segments, walls: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """For each candidate wall, points behind it over points in front (the fewer side is
    behind), counted over a sample of the scan within the wall's stretch along the floor."""
    pick = rng.choice(len(xyz), BEHIND_SAMPLE, replace=False) if len(xyz) > BEHIND_SAMPLE else None
    sample = xyz if pick is None else xyz[pick]
    shares = np.ones(len(walls))
    for i, w in enumerate(walls):
        n = s.normal[w].copy()
        n[2] = 0.0
        n /= max(np.linalg.norm(n), 1e-9)
        rel = sample - s.centre[w]
        d = rel @ n
        u = rel[:, 0] * -n[1] + rel[:, 1] * n[0]
        inside = np.abs(u) <= 0.5 * s.length[w]
        far = np.abs(d) <= BEHIND_FAR
        near = np.abs(d) >= BEHIND_NEAR
        counted = inside & far & near
        plus, minus = (
            int(np.count_nonzero(counted & (d > 0))),
            int(np.count_nonzero(counted & (d < 0))),
        )
        shares[i] = min(plus, minus) / max(plus, minus, 1)
    return shares


def read_structure(
    xyz: np.ndarray, segments: np.ndarray, spacing: float, *, seed: int = 0
) -> Structure:
    """Read floor, ceiling and walls from a levelled scan's segments (z up, metres).

    Parameters
    ----------
    xyz : ndarray of shape (N, 3)
    segments : ndarray of shape (N,), int
        Segment 0..S-1 of every point (the geometry stage's).
    spacing : float
        The scan's point spacing (m): the plane tolerance follows it.
    seed : int
        Sampling of the height ranges and behind-the-wall counts.
    """
    seg = np.asarray(segments, dtype=np.int64)
    n_seg = int(seg.max()) + 1 if len(seg) else 0
    kind = np.full(n_seg, -1, dtype=np.int64)
    confidence = np.zeros(n_seg)
    none = Structure(kind, confidence, np.zeros(len(seg), bool), None, None)
    if n_seg == 0 or np.ptp(xyz[:, 2]) < MIN_HEIGHT:
        return none  # a desk top seen alone is not a storey
    rng = np.random.default_rng(seed)
    s = _summarise(xyz, seg, n_seg, rng)
    min_points = max(20, int(MIN_SURFACE_AREA / max(spacing, 0.005) ** 2 * 0.1))
    big = s.count >= min_points
    level = s.horizontal & (s.count >= MIN_PIECE_POINTS)
    area = _footprints(xyz, seg, n_seg, level)
    pieces = np.flatnonzero(level)
    floor_z = _floor_level(s, area, pieces, float(np.quantile(xyz[:, 2], 0.005)))
    if floor_z is None:
        return none
    ceiling_z = _ceiling_level(s, area, pieces, floor_z)
    z = s.centre[:, 2]
    flat = big & s.horizontal & (area >= MIN_SURFACE_AREA)
    floor = s.horizontal & (s.count >= MIN_PIECE_POINTS) & (np.abs(z - floor_z) <= FLOOR_BAND)
    floor |= flat & (area >= 2 * MIN_LEVEL_AREA) & (z > floor_z) & (z <= floor_z + STEP)
    kind[floor] = FLOOR
    confidence[floor] = np.clip(area[floor] / (2 * MIN_LEVEL_AREA), 0.5, 1.0)
    if ceiling_z is not None:
        ceiling = level & (area >= MIN_PIECE_AREA)
        ceiling &= (z >= floor_z + MIN_STOREY) & (z >= ceiling_z - CEILING_BAND)
        kind[ceiling] = CEILING
        confidence[ceiling] = np.clip(area[ceiling] / (2 * MIN_LEVEL_AREA), 0.5, 1.0)
    _read_walls(xyz, s, big, floor_z, ceiling_z, kind, confidence, rng)
    tolerance = max(0.03, 2.5 * spacing)
    offset = np.einsum("ni,ni->n", xyz - s.centre[seg], s.normal[seg])
    on_surface = (kind[seg] >= 0) & (np.abs(offset) <= tolerance)
    return Structure(kind, confidence, on_surface, floor_z, ceiling_z)


def door_sized(s: _Segments, floor_z: float, top: float) -> np.ndarray:
    """Segments of a door leaf's size: at most DOOR_LENGTH long, standing on the floor, their
    top at most DOOR_TOP above it and half of WALL_TOP below the storey's ``top``."""
    return (
        (s.length <= DOOR_LENGTH)
        & (s.z_low <= floor_z + DOOR_FOOT)
        & (s.z_high <= floor_z + DOOR_TOP)
        & (s.z_high <= top - 0.5 * WALL_TOP)
    )


def _read_walls(
    xyz: np.ndarray,
    s: _Segments,
    big: np.ndarray,
    floor_z: float,
    ceiling_z: float | None,
    kind: np.ndarray,
    confidence: np.ndarray,
    rng: np.random.Generator,
) -> None:
    """Mark, in ``kind`` and ``confidence``, the vertical segments that are walls."""
    top = ceiling_z if ceiling_z is not None else float(np.quantile(xyz[:, 2], 0.995))
    height = max(top - floor_z, 1e-3)
    span = s.z_high - np.maximum(s.z_low, floor_z)
    upright = big & s.vertical & (s.length >= MIN_WALL_LENGTH)
    tall = upright & ((span >= WALL_SPAN * height) | (s.z_high >= top - WALL_TOP))
    # a door leaf: door-sized, with the wall going on above it up to a ceiling; without a seen
    # ceiling a wall captured only up to door height looks the same, and is far more common
    door = door_sized(s, floor_z, top) & (ceiling_z is not None)
    candidates = np.flatnonzero((tall | (upright & (span >= LOW_WALL))) & ~door)
    if len(candidates) == 0:
        return
    behind = _behind_shares(xyz, s, candidates, rng)
    reaches = np.zeros(len(candidates), bool)
    if ceiling_z is not None:
        reaches = (s.z_high[candidates] >= ceiling_z - 0.15) & (s.length[candidates] >= 1.0)
    # a low piece counts only where it bounds the scan
    wall = (behind <= BEHIND_SHARE) | (reaches & tall[candidates])
    chosen = candidates[wall]
    kind[chosen] = WALL
    bounding = np.clip(1.0 - behind[wall] / (2 * BEHIND_SHARE), 0.0, 1.0)
    share = np.clip(span[chosen] / height, 0.0, 1.0)
    confidence[chosen] = np.clip(0.5 * share + 0.5 * np.maximum(bounding, reaches[wall]), 0, 1)
    _wall_pieces(s, chosen, ~door, kind, confidence)


def _wall_pieces(
    s: _Segments, walls: np.ndarray, allowed: np.ndarray, kind: np.ndarray, confidence: np.ndarray
) -> None:
    """Walls seen only in part: smaller vertical segments in a read wall's plane, along its
    line (furniture, colour changes and holes cut a wall into pieces), read as wall with half
    that wall's confidence."""
    upright = s.upright(PIECE_TILT_DEG)
    pieces = np.flatnonzero(upright & allowed & (kind < 0) & (s.count >= WALL_PIECE_POINTS))
    if len(pieces) == 0 or len(walls) == 0:
        return
    n_w = s.normal[walls]
    rel = s.centre[pieces][:, None, :] - s.centre[walls][None, :, :]
    off = np.abs(np.einsum("pwi,wi->pw", rel, n_w))
    along = np.abs(rel[:, :, 0] * -n_w[None, :, 1] + rel[:, :, 1] * n_w[None, :, 0])
    parallel = np.abs(s.normal[pieces] @ n_w.T) >= np.cos(np.radians(PIECE_TILT_DEG))
    near = along <= 0.5 * s.length[walls][None, :] + PIECE_REACH
    fits = parallel & near & (off <= PIECE_GAP)
    found = fits.any(axis=1)
    best = np.where(fits, confidence[walls][None, :], 0.0).max(axis=1)
    kind[pieces[found]] = WALL
    confidence[pieces[found]] = 0.5 * best[found]
