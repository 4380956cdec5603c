"""The offers of the learned vote (:mod:`jointseg.fusion.learned`) and their features: every
label a point's segment, cell or the structure reading offers where the network disagrees, and
the numbers the model weighs each offer by (:data:`FEATURES`).

Why apart from the vote: the features are the contract between the run-time vote, the tree
model that reads them and the fit that learns it (:mod:`jointseg.fitting.vote`), which all
import them from here.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple, TypeVar

import numpy as np

from jointseg.classes import CLASS_INDEX, NUM_CLASSES
from jointseg.fusion.columns import ClassColumns, rows_entropy
from jointseg.fusion.fixtures import implausible_columns, implausible_doors
from jointseg.fusion.guard import segment_cells
from jointseg.geometry.structure import floor_level
from jointseg.grouping import group_sums, label_histogram, majority_label

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
#: Cell side (m) the shipped model was fitted with, when its file names none.
DEFAULT_CELL_SIZE = 0.3


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
