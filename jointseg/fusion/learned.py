"""The learned vote (beyond the paper): a point takes a label its segment offers only where a
small model, fitted on labelled rooms, says the change is more likely right than wrong.

A strong network on real scans is mostly right, and real segments mix objects (a board inside
its wall plane, clutter on a table), so eq. 7 overwrites correct minority labels; a weak network
on clean segments is the opposite case. Which case a point is in shows in numbers the vote
already has. Every point is offered up to two labels: its segment's soft-majority label and, where
that differs, the soft-majority label of its *cell* (the part of its segment inside the same
cubic cell of ``cell_size`` metres), so a board inside a wall plane can keep its board label
while specks of wrong labels around it still follow their neighbours. For each offer the model
sees the network's probability of both labels at the point, the shares of both labels in the
segment and in the cell, the segment's size, entropy and main-plane share, whether either label
is a structural class (ceiling, floor, wall), and which level made the offer; and two numbers
of the whole scan that tell a network that is at home on this sensor from one that is not: its
mean entropy, and the share of points whose label differs from their segment's majority (a
confident network that often contradicts the geometry is confidently wrong, and its segments'
majorities are no better than its points). A gradient-boosted
tree ensemble over these (``vote_model.json``, fitted by `jointseg fit vote` on tuning scans
of S3DIS, ScanNet and synthetic rooms, labelled by strong, weak and distorted networks, never on
the judging scans) gives P(the offer is right);
a point takes its most probable offer above its threshold. The threshold weighs what the
judge of the result, the mIoU, weighs (:func:`offer_thresholds`): a wrong move out of a class
the scan holds little of costs that class's IoU more than a right one gains the large class it
joins, so such offers need stronger evidence. The model is plain JSON evaluated
with numpy: no learning library is needed at run time.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Callable
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import cache, cached_property
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import numpy as np

from jointseg.classes import CLASS_INDEX, NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.fusion.columns import ClassColumns, rows_entropy
from jointseg.fusion.fixtures import implausible_columns, implausible_doors
from jointseg.fusion.guard import segment_cells
from jointseg.fusion.trees import (
    PLANS_KEPT,
    Rows,
    TreePlan,
    constant_features,
    plan_tree,
    raw_scores,
    split_thresholds,
    varying_cuts,
)
from jointseg.geometry.structure import floor_level
from jointseg.grouping import group_sums, label_histogram, majority_label

#: The model shipped with the library.
MODEL_PATH = Path(__file__).with_name("vote_model.json")
#: Names of the features, in the order the model expects them.
FEATURES = (
    "logit p(own)",
    "logit p(offer)",
    "logit segment soft share of offer",
    "logit segment soft share of own",
    "logit segment hard share of offer",
    "log10 segment share of the scan",
    "segment mean entropy",
    "point entropy",
    "logit cell soft share of offer",
    "logit cell soft share of own",
    "log10 cell share of its segment",
    "segment main-plane share",
    "own label is structural",
    "offer is structural",
    "offer is the segment's label",
    "scan mean entropy",
    "scan share off its segment's majority",
    "structure reads the offer",
    "structure reads own",
    "offer only from structure",
    "own label is a wall fixture",
    "scan has colour",
)
#: The features that vary from point to point among offers of one :attr:`Offers.context`.
POINT_FEATURES = tuple(
    FEATURES.index(name)
    for name in (
        "logit p(own)",
        "logit p(offer)",
        "point entropy",
        "structure reads the offer",
        "structure reads own",
    )
)
#: The features of a model fitted before the structure reading (issue 43): such a model is
#: still read, evaluated on these columns only, and is never offered the structure's labels.
FEATURES_BEFORE_STRUCTURE = FEATURES[:17]
#: Probabilities are clipped to [EPS, 1 - EPS] before the logit (taken in float64, as the
#: entropy is: see :func:`normalised_entropy`).
EPS = 1e-4
#: :class:`ClassTally` sums the probabilities in blocks of this many rows (their rounding is
#: the model's thresholds'; the name is from when the entropy was taken in such blocks too).
ENTROPY_BLOCK = 1 << 18
#: Rows of a block :class:`ClassTally` converts to float64 at once.
TALLY_ROWS = 1 << 13
#: Classes that are the room's shell: a label moving between them and an object class is the
#: vote's riskiest change (a board in its wall plane), so the model sees it.
STRUCTURAL = np.zeros(NUM_CLASSES, dtype=bool)
STRUCTURAL[[CLASS_INDEX["ceiling"], CLASS_INDEX["floor"], CLASS_INDEX["wall"]]] = True
#: Classes that lie in or against the room's shell (a window, door or board in a wall's plane, a
#: column in it, a beam under the ceiling): the structure reading may well include them, and
#: the network keeps them where it sees them.
FIXTURE = np.zeros(NUM_CLASSES, dtype=bool)
FIXTURE[[CLASS_INDEX[c] for c in ("window", "door", "board", "column", "beam")]] = True
#: Whether the vote works out its entropies, wall fixtures and class tally in threads beside
#: its sums (the same results either way; 0 runs everything in the caller's thread).
WORKERS = 1
#: :func:`offer_thresholds` counts every class as at least this share of the scan (a class
#: of a few points would otherwise ask for certainty, or be joined on no evidence).
MIN_CLASS_SHARE = 0.001
#: :meth:`ClassTally.ious` takes no class's expected IoU as lower than this (a class the
#: network seems never to find right would otherwise hold its points against any evidence).
MIN_EXPECTED_IOU = 0.4
#: Cell side (m) the shipped model was fitted with, when its file names none.
DEFAULT_CELL_SIZE = 0.3
#: A wall fixture the network sees keeps its label against a wall that only the structure
#: reading offers: the network's soft share of the fixture in the point's cell is above this
#: (:func:`seen_fixtures`; 1 turns the rule off).
SEEN_FIXTURE_SHARE = 0.7


def _logit(x: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(x, dtype=np.float64), EPS, 1 - EPS)
    return np.log(x / (1 - x))


#: Per-segment column sums of weights (N, C), shape (n_seg, C); the old name of
#: :func:`jointseg.grouping.group_sums`, kept for ``bench/graph_probe.py``.
segment_label_sums = group_sums


class StructureHint(NamedTuple):
    """The geometry's structural reading at every point (:mod:`jointseg.geometry.structure`),
    evidence that uses no labels.

    Attributes
    ----------
    kind : ndarray of shape (N,), int
        The class the geometry reads (floor, ceiling or wall), -1 where it reads none.
    confidence : ndarray of shape (N,), float
        How sure it is, in [0, 1].
    """

    kind: np.ndarray
    confidence: np.ndarray


@dataclass(frozen=True)
class Offers:
    """The labels a vote offers points that the network labelled otherwise.

    Attributes
    ----------
    point : ndarray of shape (M,), int64
        Index of the point each offer is made to (a point gets at most two).
    label : ndarray of shape (M,), int64
        The offered label (never the point's network label).
    features : ndarray of shape (M, len(FEATURES)), float64
    segment_label : ndarray of shape (N,), int64
        The segment's soft-majority label at every point.
    segment_votes : ndarray of shape (S, C), float64
        Summed probabilities per segment and class (the soft vote of eq. 6).
    context : ndarray of shape (M,), int64, optional
        Offers with equal context (the cell, own and offered class, whether the own label is
        a believable fixture, where the offer comes from) have equal features except
        :data:`POINT_FEATURES`: :meth:`TreeEnsemble.probability` takes their other splits once.
    """

    point: np.ndarray
    label: np.ndarray
    features: np.ndarray
    segment_label: np.ndarray
    segment_votes: np.ndarray
    context: np.ndarray | None = None


def normalised_entropy(probs: np.ndarray) -> np.ndarray:
    """Entropy of each row of ``probs`` (N, C) divided by log C: 0 sure, 1 uniform.

    Taken in float64, a block of rows at a time: numpy's float32 logarithm differs in the last
    bit between its SIMD paths (with AVX2 or without), and those bits moved the thresholds of
    a refitted vote from one machine to another."""
    return rows_entropy(probs)


def _shares(
    unit: np.ndarray, n_units: int, columns: ClassColumns
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points per unit, summed probabilities and mean probabilities (soft shares):
    (U,), (U, C) and (U, C)."""
    size = np.bincount(unit, minlength=n_units).astype(np.float64)
    sums = columns.sums(unit, n_units)
    return size, sums, sums / np.maximum(size, 1)[:, None]


def disagreement_share(seg: np.ndarray, n_seg: int, labels: np.ndarray) -> float:
    """Share of points whose network label is not their segment's most common label."""
    if len(labels) == 0:
        return 0.0
    return float(np.mean(majority_label(seg, n_seg, labels, NUM_CLASSES)[seg] != labels))


def _no_offers(n_seg: int, n_classes: int) -> Offers:
    """Offers of an empty point set: nothing offered, every segment with zero votes."""
    none = np.zeros(0, dtype=np.int64)
    votes = np.zeros((n_seg, n_classes))
    return Offers(none, none, np.zeros((0, len(FEATURES))), none, votes)


def _plane_share(
    seg: np.ndarray, n_seg: int, seg_size: np.ndarray, main_plane: np.ndarray | None
) -> np.ndarray:
    """Share of each segment's points on a main plane (zeros when no planes were given)."""
    return (
        np.zeros(n_seg)
        if main_plane is None
        else np.bincount(seg, weights=main_plane.astype(np.float64), minlength=n_seg)
        / np.maximum(seg_size, 1)
    )


def _pick_offers(
    labels: np.ndarray,
    seg_label: np.ndarray,
    cell_label: np.ndarray,
    probs: np.ndarray,
    min_support: float,
    structure: StructureHint | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points, offered classes, whether each offer comes from the segment (else the cell or
    the structure) and whether only the structure reading makes it.

    Segment offers come first; a cell offers only where it disagrees with the segment too, and
    the structure only where it disagrees with both, so no point gets the same offer twice.
    ``min_support`` holds back the segment's and cell's offers only: the structure reading is
    evidence the network's probabilities do not contain.
    """
    by_segment = np.flatnonzero(seg_label != labels)
    by_cell = np.flatnonzero((cell_label != labels) & (cell_label != seg_label))
    point = np.concatenate([by_segment, by_cell])
    offer = np.concatenate([seg_label[by_segment], cell_label[by_cell]])
    from_segment = np.arange(len(point)) < len(by_segment)
    if min_support > 0:
        supported = _at(probs, point, offer) >= min_support
        point, offer, from_segment = point[supported], offer[supported], from_segment[supported]
    only_structure = np.zeros(len(point), dtype=bool)
    if structure is not None:
        sk = np.asarray(structure.kind, dtype=np.int64)
        by_structure = np.flatnonzero(
            (sk >= 0) & (sk != labels) & (sk != seg_label) & (sk != cell_label)
        )
        point = np.concatenate([point, by_structure])
        offer = np.concatenate([offer, sk[by_structure]])
        from_segment = np.concatenate([from_segment, np.zeros(len(by_structure), bool)])
        only_structure = np.concatenate([only_structure, np.ones(len(by_structure), bool)])
    return point, offer, from_segment, only_structure


def _unbelievable(
    xyz: np.ndarray, labels: np.ndarray, structure: StructureHint | None
) -> np.ndarray:
    """Points the network labelled a door or column of no believable size or place (bool, N;
    :func:`implausible_doors`, :func:`implausible_columns`), the floor level the structure
    reading's."""
    floor_z = None if structure is None else floor_level(xyz[:, 2], structure.kind)
    return implausible_doors(xyz, labels, floor_z) | implausible_columns(xyz, labels)


def _structure_columns(
    structure: StructureHint | None,
    point: np.ndarray,
    offer: np.ndarray,
    own: np.ndarray,
    only_structure: np.ndarray,
    unbelievable: np.ndarray,
) -> list[np.ndarray]:
    """The structure reading's features of each offer: how sure it is of the offer and of
    the point's own label, whether only it makes the offer, whether the own label is a wall
    fixture of a believable size (not ``unbelievable``, :func:`_unbelievable`)."""
    fixture = FIXTURE[own] & ~unbelievable[point]
    reads_offer = reads_own = np.zeros(len(point))
    if structure is not None:
        kind = np.asarray(structure.kind, dtype=np.int64)
        sure = np.asarray(structure.confidence, dtype=np.float64)[point]
        reads_offer = np.where(kind[point] == offer, sure, 0.0)
        reads_own = np.where(kind[point] == own, sure, 0.0)
    return [reads_offer, reads_own, only_structure, fixture]


def vote_offers(
    xyz: np.ndarray,
    seg: np.ndarray,
    n_seg: int,
    labels: np.ndarray,
    probs: np.ndarray,
    *,
    cell_size: float = DEFAULT_CELL_SIZE,
    main_plane: np.ndarray | None = None,
    min_support: float = 0.0,
    totals: tuple[int, float, float] | None = None,
    structure: StructureHint | None = None,
    has_colour: bool = True,
) -> Offers:
    """Every offer of a segment or cell label to a point whose network label differs, except
    offers of a class the network gave the point less than ``min_support`` probability; and,
    with ``structure``, the geometry's structural reading where it differs from all of these.

    Parameters
    ----------
    xyz, seg, n_seg, labels, probs
        Points (N, 3) in metres, their segment 0..n_seg-1, the network's labels and
        probabilities (N, C), rows summing to 1.
    cell_size : float
        Side (m) of the cubic cells that cut segments into local voting units.
    main_plane : ndarray of shape (N,), bool, optional
        Points on the geometry's main planes (walls, floor, ceiling); none when not given.
    min_support : float
        Least probability of the offered class at the point (0 keeps every offer).
    totals : (int, float, float), optional
        The whole scan's point count, mean normalised entropy and :func:`disagreement_share`
        when these points are a part of it made of whole segments (a tiled run).
    structure : StructureHint, optional
        The geometry's floor, ceiling and wall reading per point; none when not given.
    has_colour : bool
        Whether the scan had usable colour (without it, segments merge more).
    """
    n, n_classes = probs.shape
    labels = np.asarray(labels, dtype=np.int64)
    if n == 0:
        return _no_offers(n_seg, n_classes)
    columns = ClassColumns.of(probs)
    # the entropies, the doors' and columns' sizes and the cells' votes are worked out beside
    # the segments' votes (numpy lets go of the GIL in its loops: a second core shares them)
    with _workers(3) as pool:
        entropy_job = pool.submit(columns.entropy)
        unbelievable_job = pool.submit(_unbelievable, xyz, labels, structure)
        cells_job = pool.submit(_cell_shares, xyz, seg, n_seg, cell_size, columns)
        seg_size, seg_votes, seg_soft = _shares(seg, n_seg, columns)
        counts = label_histogram(seg, n_seg, labels, n_classes)
        seg_hard = counts / np.maximum(seg_size, 1)[:, None]
        cell, n_cells, cell_count, cell_soft = cells_job.result()
        seg_label, cell_label = seg_soft.argmax(axis=1)[seg], cell_soft.argmax(axis=1)[cell]
        point, offer, from_segment, only_structure = _pick_offers(
            labels, seg_label, cell_label, probs, min_support, structure
        )
        entropy = entropy_job.result()
        unbelievable = unbelievable_job.result()
    del columns
    if totals is None:
        totals = (n, float(entropy.mean()), _disagreement(seg, n_seg, labels, counts))
    scan_points, scan_entropy, scan_disagreement = totals
    seg_entropy = np.bincount(seg, weights=entropy, minlength=n_seg) / np.maximum(seg_size, 1)
    plane_share = _plane_share(seg, n_seg, seg_size, main_plane)
    s, c, own = seg[point], cell[point], labels[point]
    seg_of_cell = np.zeros(n_cells, dtype=np.int64)
    seg_of_cell[c] = s
    structure_cols = _structure_columns(structure, point, offer, own, only_structure, unbelievable)
    cols = _feature_columns(
        probs, point, own, offer, (seg_soft, seg_hard, cell_soft), s, c,
        (seg_size, seg_entropy, plane_share, entropy), cell_count, seg_of_cell, from_segment,
        (scan_points, scan_entropy, scan_disagreement), structure_cols, has_colour,
    )  # fmt: skip
    fixture = structure_cols[3]
    context = (((c * n_classes + own) * n_classes + offer) * 2 + fixture) * 4
    context += from_segment * 2 + only_structure
    segment_label = np.asarray(seg_label, dtype=np.int64)
    return Offers(point, offer, cols.T, segment_label, seg_votes, context)


def _feature_columns(
    probs: np.ndarray,
    point: np.ndarray,
    own: np.ndarray,
    offer: np.ndarray,
    votes: tuple[np.ndarray, np.ndarray, np.ndarray],
    s: np.ndarray,
    c: np.ndarray,
    per_segment: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    cell_count: np.ndarray,
    seg_of_cell: np.ndarray,
    from_segment: np.ndarray,
    scan: tuple[int, float, float],
    structure_cols: tuple[np.ndarray, ...] | list[np.ndarray],
    has_colour: bool,
) -> np.ndarray:
    """The offers' features, one row per :data:`FEATURES` name (filled in its order)."""
    seg_soft, seg_hard, cell_soft = votes
    seg_size, seg_entropy, plane_share, entropy = per_segment
    scan_points, scan_entropy, scan_disagreement = scan
    cols = np.empty((len(FEATURES), len(point)))
    cols[0] = _logit(_at(probs, point, own))
    cols[1] = _logit(_at(probs, point, offer))
    cols[2] = _logit_at(seg_soft, s, offer)
    cols[3] = _logit_at(seg_soft, s, own)
    cols[4] = _logit_at(seg_hard, s, offer)
    cols[5] = np.log10(seg_size / max(scan_points, 1))[s]
    cols[6] = seg_entropy[s]
    cols[7] = entropy[point]
    cols[8] = _logit_at(cell_soft, c, offer)
    cols[9] = _logit_at(cell_soft, c, own)
    cols[10] = _cell_share(cell_count, seg_size, seg_of_cell, c, s)
    cols[11] = plane_share[s]
    cols[12] = STRUCTURAL[own]
    cols[13] = STRUCTURAL[offer]
    cols[14] = from_segment
    cols[15] = scan_entropy
    cols[16] = scan_disagreement
    for i, col in enumerate(structure_cols):
        cols[17 + i] = col
    cols[21] = float(has_colour)
    return cols


def _workers(n: int) -> Executor:
    """Threads for work done beside the caller's (:data:`WORKERS` 0: none, run in place)."""
    return ThreadPoolExecutor(max_workers=n) if WORKERS else _InPlace()


class _InPlace(Executor):
    """An executor that runs each job when it is submitted."""

    def submit(self, fn: Callable[..., T], /, *args: Any, **kwargs: Any) -> Future[T]:
        done: Future[T] = Future()
        try:
            done.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # handed to the caller by result(), as a thread would
            done.set_exception(exc)
        return done


def _at(probs: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``probs[rows, cols]``, gathered from the flat array (faster for a C-contiguous one)."""
    if not probs.flags.c_contiguous:
        return probs[rows, cols]
    return np.take(probs.reshape(-1), rows * probs.shape[1] + cols)


def _logit_at(table: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
    """``_logit(table[row, col])``, the logit taken over the table where it is the smaller."""
    flat = row * table.shape[1] + col
    if table.size <= len(row):
        return np.take(_logit(table).reshape(-1), flat)
    return _logit(np.take(table.reshape(-1), flat))


def _cell_share(
    cell_count: np.ndarray,
    seg_size: np.ndarray,
    seg_of_cell: np.ndarray,
    c: np.ndarray,
    s: np.ndarray,
) -> np.ndarray:
    """log10 of each offer's cell's share of its segment (``s``: the segment of cell ``c``),
    taken per cell where there are fewer cells than offers."""
    if len(cell_count) <= len(c):
        return np.log10(cell_count / np.maximum(seg_size[seg_of_cell], 1))[c]
    return np.log10(cell_count[c] / np.maximum(seg_size[s], 1))


def _cell_shares(
    xyz: np.ndarray, seg: np.ndarray, n_seg: int, cell_size: float, columns: ClassColumns
) -> tuple[np.ndarray, int, np.ndarray, np.ndarray]:
    """Every point's cell (its segment cut into cubes of ``cell_size``; the segment where 0),
    the number of cells, their sizes and soft shares (:func:`_shares`)."""
    cell, n_cells = segment_cells(xyz, seg, cell_size) if cell_size > 0 else (seg, n_seg)
    size, _, soft = _shares(cell, n_cells, columns)
    return cell, n_cells, size, soft


def _disagreement(seg: np.ndarray, n_seg: int, labels: np.ndarray, counts: np.ndarray) -> float:
    """:func:`disagreement_share` from the segments' label counts (N, C) already taken."""
    if counts.shape[1] != NUM_CLASSES:
        return disagreement_share(seg, n_seg, labels)
    majority = np.where(counts.sum(axis=1) > 0, counts.argmax(axis=1), -1)
    return float(np.mean(majority[seg] != labels))


T = TypeVar("T")

#: Guards each model's cache of specialised trees (fusions may run in threads).
_PLANS_LOCK = threading.Lock()


@dataclass(frozen=True)
class TreeEnsemble:
    """Gradient-boosted binary trees: P(change is right) = sigmoid(base + sum of leaf values).

    Each tree is stored as flat arrays; node 0 is the root, a point goes left where
    ``x[feature] <= threshold``.
    """

    base: float
    feature: list[np.ndarray]
    threshold: list[np.ndarray]
    left: list[np.ndarray]
    right: list[np.ndarray]
    value: list[np.ndarray]
    leaf: list[np.ndarray]
    card: dict
    cell_size: float = DEFAULT_CELL_SIZE
    n_features: int = len(FEATURES)

    @property
    def weighs_structure(self) -> bool:
        """Whether the model was fitted with the structure reading's offers and features."""
        return self.n_features == len(FEATURES)

    @classmethod
    def from_json(cls, path: Path) -> TreeEnsemble:
        """Read a model written by `jointseg fit vote`; a missing file is a ConfigError naming
        it (an installation without the shipped model must not fuse without it)."""
        if not path.is_file():
            incomplete = ": the jointseg installation is incomplete; reinstall jointseg"
            why = incomplete if path == MODEL_PATH else ""
            raise ConfigError(f"the vote model {path} is missing{why}")
        try:
            body = json.loads(path.read_text())
            trees = body["trees"]
            if body["features"] not in (list(FEATURES), list(FEATURES_BEFORE_STRUCTURE)):
                raise ConfigError(f"{path}: features {body['features']} are not {list(FEATURES)}")
            cell_size = float(body.get("cell_size", DEFAULT_CELL_SIZE))
            if not np.isfinite(cell_size) or cell_size < 0:
                raise ConfigError(f"{path}: cell_size must be a length >= 0 (m), got {cell_size}")
            return cls(
                base=float(body["base"]),
                feature=[np.asarray(t["feature"], np.int64) for t in trees],
                threshold=[np.asarray(t["threshold"], np.float64) for t in trees],
                left=[np.asarray(t["left"], np.int64) for t in trees],
                right=[np.asarray(t["right"], np.int64) for t in trees],
                value=[np.asarray(t["value"], np.float64) for t in trees],
                leaf=[np.asarray(t["leaf"], bool) for t in trees],
                card=dict(body.get("card", {})),
                cell_size=cell_size,
                n_features=len(body["features"]),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ConfigError(f"vote model {path}: {exc}") from exc

    def probability(self, x: np.ndarray, context: np.ndarray | None = None) -> np.ndarray:
        """P(the change is right) for every row of ``x`` (M, F): the sigmoid of
        :meth:`decision`."""
        return 1.0 / (1.0 + np.exp(-self.decision(x, context)))

    def decision(self, x: np.ndarray, context: np.ndarray | None = None) -> np.ndarray:
        """The ensemble's raw score (log-odds) for every row of ``x`` (M, F): its base plus
        each tree's leaf value, added in the trees' order (:mod:`jointseg.fusion.trees`).

        ``context`` (M,), optional: rows with equal context have equal features except
        :data:`POINT_FEATURES` (:attr:`Offers.context`); their other splits are then taken once
        per context. The result is the same to the bit with it or without."""
        x = np.asarray(x, dtype=np.float64)[:, : self.n_features]
        if len(x) == 0:
            return np.zeros(0)
        varying = frozenset(POINT_FEATURES if context is not None else ())
        plans, cuts = self._plans(constant_features(x, self._used_features), varying)
        rows = Rows.each(len(x)) if context is None else Rows.grouped(x, context, cuts)
        raw = raw_scores(self, x, plans, rows)
        return raw if rows.inverse is None else raw[rows.inverse]

    @cached_property
    def _thresholds(self) -> list[np.ndarray]:
        """Per feature, the sorted distinct thresholds of its splits."""
        return split_thresholds(self, self.n_features)

    @cached_property
    def _used_features(self) -> list[int]:
        """The features some split tests."""
        return [f for f, cuts in enumerate(self._thresholds) if len(cuts)]

    @cached_property
    def _plan_cache(self) -> dict[tuple, tuple[list[TreePlan], dict[int, np.ndarray]]]:
        return {}

    def _plans(
        self, fixed: dict[int, float], varying: frozenset[int]
    ) -> tuple[list[TreePlan], dict[int, np.ndarray]]:
        """Every tree specialised to the constant features ``fixed``, and the thresholds of
        the ``varying`` features' splits left (kept for the next call with the same constants:
        the tiles of a scan share them)."""
        key = (tuple(sorted(fixed.items())), varying)
        with _PLANS_LOCK:
            cache = self._plan_cache
            if key not in cache:
                if len(cache) >= PLANS_KEPT:
                    cache.pop(next(iter(cache)))
                plans = [plan_tree(self, t, fixed, varying) for t in range(len(self.feature))]
                cache[key] = plans, varying_cuts(plans)
            return cache[key]


@cache
def shipped_model() -> TreeEnsemble:
    """The model shipped with the library (read once per process)."""
    return TreeEnsemble.from_json(MODEL_PATH)


@dataclass(frozen=True)
class ClassTally:
    """What the network's output says of each class over a scan, for :func:`offer_thresholds`:
    the points it gave the class, the class's probability summed over every point (the points
    expected truly of the class) and, over the points it gave the class, that probability
    summed (those expected right). Parts of a scan (tiles) add up.

    Attributes
    ----------
    counts, expected, agreed : ndarray of shape (C,), float64
    """

    counts: np.ndarray
    expected: np.ndarray
    agreed: np.ndarray

    @classmethod
    def of(cls, labels: np.ndarray, probs: np.ndarray) -> ClassTally:
        """The tally of points labelled ``labels`` (N,) with probabilities ``probs`` (N, C)."""
        labels = np.asarray(labels, dtype=np.int64)
        n_classes = probs.shape[1]
        own = _at(probs, np.arange(len(labels)), labels)
        return cls(
            counts=np.bincount(labels, minlength=n_classes).astype(np.float64),
            expected=_expected(probs),
            agreed=np.bincount(labels, weights=own, minlength=n_classes),
        )

    @classmethod
    def empty(cls, n_classes: int = NUM_CLASSES) -> ClassTally:
        """The tally of no points."""
        return cls(np.zeros(n_classes), np.zeros(n_classes), np.zeros(n_classes))

    def __add__(self, other: ClassTally) -> ClassTally:
        return ClassTally(
            self.counts + other.counts,
            self.expected + other.expected,
            self.agreed + other.agreed,
        )

    def _union(self) -> np.ndarray:
        """Each class's expected union of truth and labels, as tallied."""
        return self.expected + self.counts - self.agreed

    def unions(self) -> np.ndarray:
        """Each class's expected union of truth and labels (:func:`at_least_min_share`)."""
        return at_least_min_share(self._union(), float(self.counts.sum()))

    def ious(self) -> np.ndarray:
        """Each class's expected IoU, at least :data:`MIN_EXPECTED_IOU`."""
        union = self._union()
        iou = np.where(union > 0, self.agreed / np.maximum(union, 1e-12), 1.0)
        return np.clip(iou, MIN_EXPECTED_IOU, 1.0)


def _expected(probs: np.ndarray) -> np.ndarray:
    """Each class's probability summed over the rows of ``probs`` (N, C) in float64: per block
    of ENTROPY_BLOCK rows, row after row (as numpy sums a C-contiguous block's first axis), the
    blocks' sums then added. A block is converted a part of TALLY_ROWS rows at a time into one
    small buffer whose first row carries the block's sum so far, and summed by ``np.bincount``
    over the flat buffer with each value's class as its bin (it adds in order, the classes side
    by side), so the sums round as over the whole block."""
    n, n_classes = probs.shape
    expected = np.zeros(n_classes)
    buf = np.empty((min(n, TALLY_ROWS) + 1, n_classes))
    bins = np.tile(np.arange(n_classes), len(buf))
    for start in range(0, n, ENTROPY_BLOCK):
        stop = min(start + ENTROPY_BLOCK, n)
        block_sum: np.ndarray = np.zeros(n_classes)
        for part in range(start, stop, TALLY_ROWS):
            rows = min(TALLY_ROWS, stop - part)
            buf[0] = block_sum
            np.copyto(buf[1 : rows + 1], probs[part : part + rows])
            size = (rows + 1) * n_classes
            block_sum = np.bincount(bins[:size], buf.reshape(-1)[:size], n_classes)
        expected += block_sum
    return expected


def at_least_min_share(sizes: np.ndarray, points: float) -> np.ndarray:
    """Class sizes, each at least :data:`MIN_CLASS_SHARE` of a scan of ``points`` (a class of a
    few points would otherwise ask for certainty, or be joined on no evidence)."""
    return np.maximum(sizes, MIN_CLASS_SHARE * max(points, 1.0))


def offer_thresholds(
    tally: ClassTally,
    own: np.ndarray,
    offer: np.ndarray,
    threshold: float,
    metric_iou: float | str,
) -> np.ndarray:
    """The least P(right) at which each offer is taken, so that a taken offer raises the
    expected mIoU (the metric every class counts in alike).

    Moving one point from class a (``own``) to b (``offer``) changes the IoUs, to first order
    in the classes' unions U and IoUs k, by ``k_a / U_a + 1 / U_b`` where the offer is right
    and by ``-(1 / U_a + k_b / U_b)`` where the network was. The offer pays where its odds
    exceed the ratio of the two, times the odds of ``threshold``: out of a class the scan has
    little of (a board in its wall) it asks for more, into one for less, and out of a class
    the network finds poorly (k_a small: taking its false points away gains it little, taking
    its true ones loses it much) for more still.

    ``metric_iou`` "auto": U and k are those the network's own probabilities expect
    (:meth:`ClassTally.unions`, :meth:`ClassTally.ious`). A number: one guess of k for all
    classes, U the network's counts (at least :data:`MIN_CLASS_SHARE` of the scan); 1 gives
    ``threshold`` everywhere."""
    if metric_iou == "auto":
        u, k = tally.unions(), tally.ious()
    elif float(metric_iou) >= 1:
        return np.full(len(own), threshold, dtype=np.float64)
    else:
        u = at_least_min_share(tally.counts, float(tally.counts.sum()))
        k = np.full(len(u), float(metric_iou))
    ua, ub, ka, kb = u[own], u[offer], k[own], k[offer]
    base = threshold / max(1.0 - threshold, EPS)
    odds = base * (1 / ua + kb / ub) / (ka / ua + 1 / ub)
    return odds / (1 + odds)


def seen_fixtures(
    features: np.ndarray, offer: np.ndarray, share: float = SEEN_FIXTURE_SHARE
) -> np.ndarray:
    """Offers never taken (bool, M): a wall offered only by the structure reading to a point
    the network labels a believable wall fixture, in a cell the network gives mostly to that
    fixture. The reading cannot tell a board or window from its wall; where the network sees
    one, the vote keeps it, whatever the model learned of such offers on average (without
    colour, a whiteboard and its wall are one segment, and the model moved the board)."""
    if features.shape[1] < len(FEATURES) or share >= 1:
        return np.zeros(len(offer), dtype=bool)
    col = FEATURES.index
    return (
        (features[:, col("own label is a wall fixture")] > 0.5)
        & (features[:, col("offer only from structure")] > 0.5)
        & (np.asarray(offer) == CLASS_INDEX["wall"])
        & (features[:, col("logit cell soft share of own")] > _logit(np.array([share]))[0])
    )


def best_offers(
    labels: np.ndarray,
    point: np.ndarray,
    label: np.ndarray,
    p: np.ndarray,
    threshold: float | np.ndarray,
) -> np.ndarray:
    """``labels`` (copied, int64) with each point's most probable offer above ``threshold``
    (one for all, or one per offer) taken; ``point``, ``label`` and ``p`` describe the
    offers."""
    fused = np.asarray(labels, dtype=np.int64).copy()
    take = np.flatnonzero(p > threshold)
    if len(take) == 0:
        return fused
    # a point with two accepted offers takes the more probable one (the first of equals)
    at, p_take = point[take], p[take]
    best = np.full(len(fused), -np.inf)
    np.maximum.at(best, at, p_take)
    won = p_take == best[at]
    first = np.full(len(fused), len(take))
    np.minimum.at(first, at[won], np.flatnonzero(won))
    chosen = take[first[at[won]]]
    fused[point[chosen]] = label[chosen]
    return fused


def learned_labels(
    xyz: np.ndarray,
    seg: np.ndarray,
    n_seg: int,
    labels: np.ndarray,
    probs: np.ndarray,
    *,
    threshold: float,
    min_support: float = 0.0,
    main_plane: np.ndarray | None = None,
    model: TreeEnsemble | None = None,
    totals: tuple[int, float, float] | None = None,
    structure: StructureHint | None = None,
    has_colour: bool = True,
    metric_iou: float | str = 1.0,
    classes: ClassTally | None = None,
    seen_fixture_share: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Fused labels: each point's most probable offer where the model's P(right) exceeds
    its threshold (:func:`offer_thresholds` of ``threshold`` and ``metric_iou``), else the
    network's label. An offer of a class the network gave the point less than ``min_support``
    probability is never taken. ``structure`` (the geometry's floor, ceiling and wall reading)
    is offered too where the model was fitted with it. ``classes``: the network's
    :class:`ClassTally` over the whole scan, where these points are a part of it (a tile);
    else tallied here. ``seen_fixture_share``: the :func:`seen_fixtures` rule's share (1, the
    default here, leaves it out; ``FusionParams`` turns it on).

    Returns
    -------
    labels : ndarray of shape (N,), int64
    segment_votes : ndarray of shape (n_seg, C), float64
        Summed probabilities per segment and class.
    """
    model = model or shipped_model()
    labels = np.asarray(labels, dtype=np.int64)
    weigh_classes = metric_iou == "auto" or float(metric_iou) < 1
    with _workers(1) as pool:
        tally_job = None
        if weigh_classes and classes is None:
            tally_job = pool.submit(ClassTally.of, labels, probs)
        offers = vote_offers(
            xyz,
            seg,
            n_seg,
            labels,
            probs,
            cell_size=model.cell_size,
            main_plane=main_plane,
            min_support=min_support,
            totals=totals,
            structure=structure if model.weighs_structure else None,
            has_colour=has_colour,
        )
        p = model.probability(offers.features, offers.context) if len(offers.point) else np.zeros(0)
        tally = classes if tally_job is None else tally_job.result()
    p = np.where(seen_fixtures(offers.features, offers.label, seen_fixture_share), 0.0, p)
    at: float | np.ndarray = threshold
    if weigh_classes:
        assert tally is not None
        own = labels[offers.point]
        at = offer_thresholds(tally, own, offers.label, threshold, metric_iou)
    return best_offers(labels, offers.point, offers.label, p, at), offers.segment_votes
