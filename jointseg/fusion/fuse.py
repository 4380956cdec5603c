"""Label fusion (§2.3): inside every geometric segment, minority network labels give way to the
segment's majority label.

Everything is a handful of ``np.bincount`` calls over (segment, class) keys: linear in the
number of points, no Python loop over points or segments.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.fusion import evidence, guard, learned
from jointseg.fusion.offers import StructureHint
from jointseg.fusion.params import GUARDED_MODES, SOFT_MODES, FusionParams
from jointseg.fusion.thresholds import ClassTally
from jointseg.fusion.transfer import transfer_labels
from jointseg.grouping import compact_ids, group_sums, label_histogram

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ScanTotals:
    """Scan-wide values some votes use, given when a scan is fused in parts (tiles) so every
    part votes as it would inside the whole scan.

    Attributes
    ----------
    points : int
        Points in the whole scan (segment sizes are judged as shares of it).
    mean_entropy : float
        Mean normalised entropy of the network's probabilities over the whole scan
        (:func:`jointseg.fusion.offers.normalised_entropy`).
    disagreement : float
        Share of the whole scan's points whose network label is not their segment's most
        common label (:func:`jointseg.fusion.offers.disagreement_share`).
    classes : ClassTally, optional
        The whole scan's network output per class (the learned vote's thresholds,
        :func:`jointseg.fusion.thresholds.offer_thresholds`); tallied in the part when not given.
    """

    points: int
    mean_entropy: float
    disagreement: float
    classes: ClassTally | None = None


@dataclass(frozen=True)
class FusionResult:
    """Fused labels and confidence for every point, and what each segment's vote decided.

    Attributes
    ----------
    labels : ndarray of shape (N,), int32
        Fused class per point.
    confidence : ndarray of shape (N,), float32
        Mean of the network's probability for the fused label at the point (1/0 for agreeing /
        disagreeing hard labels when no probabilities were given) and the fused label's vote
        share in the point's voting unit: 1 only when the point and its whole segment agree.
    network_labels : ndarray of shape (N,), int32
        The network labels the vote started from (after the nearest-neighbour transfer).
    segment_ids : ndarray of shape (S,), int64
        The segment id each per-segment row describes (sorted).
    segment_label : ndarray of shape (S,), int32
        L_max, the majority label of each segment (eq. 7).
    segment_share : ndarray of shape (S,), float32
        Its share of the segment's votes (eq. 6).
    segment_kept : ndarray of shape (S,), bool
        The guard kept the network labels of the whole segment (impure, no cells to split into).
    segment_split : ndarray of shape (S,), bool
        The guard split the segment (impure) into cells that voted on their own.
    """

    labels: np.ndarray
    confidence: np.ndarray
    network_labels: np.ndarray
    segment_ids: np.ndarray
    segment_label: np.ndarray
    segment_share: np.ndarray
    segment_kept: np.ndarray
    segment_split: np.ndarray
    params: FusionParams
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def n_segments(self) -> int:
        """Number of segments."""
        return len(self.segment_ids)

    @property
    def changed(self) -> np.ndarray:
        """Boolean mask of points whose label the fusion changed."""
        return self.labels != self.network_labels


def fuse(
    xyz: np.ndarray,
    segments: np.ndarray,
    network_labels: np.ndarray,
    network_probs: np.ndarray | None = None,
    params: FusionParams | None = None,
    *,
    network_xyz: np.ndarray | None = None,
    main_plane: np.ndarray | None = None,
    totals: ScanTotals | None = None,
    structure: StructureHint | None = None,
    has_colour: bool = True,
) -> FusionResult:
    """Combine network labels with geometric segments (eq. 6-7 and the modes beyond them).

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), metres
        The segmented points.
    segments : ndarray of shape (N,), int
        Segment id per point (non-negative; need not be contiguous).
    network_labels : ndarray of shape (M,), int
        Network class per point, 0..12; M = N unless ``network_xyz`` is given.
    network_probs : ndarray of shape (M, 13), optional
        Network class probabilities, voted with in the soft modes and used for the confidence.
        Without them the soft modes count hard labels (one-hot probabilities), as the paper.
    params : FusionParams, optional
    network_xyz : ndarray of shape (M, 3), metres, optional
        The points the network labelled when they are not ``xyz`` (e.g. a sub-sample); labels
        reach ``xyz`` through a K-nearest-neighbour majority (``params.neighbours``).
    main_plane : ndarray of shape (N,), bool, optional
        Points on the geometry's main planes (``GeometryResult.main_plane``): the learned vote
        weighs an offer from a wall or floor plane differently from one from an object.
    totals : ScanTotals, optional
        Scan-wide values when ``xyz`` is a part of a scan made of whole segments (a tiled
        run); default: ``xyz`` is the whole scan.
    structure : StructureHint, optional
        The geometry's floor, ceiling and wall reading per point (``GeometryResult.structure``
        and ``structure_confidence``): the learned vote offers it as a label of its own, even
        where the network's majority says otherwise. The other modes ignore it.
    has_colour : bool
        Whether the scan had usable colour (the learned vote weighs offers differently on
        colour-free scans, whose segments merge more).

    Returns
    -------
    FusionResult

    Raises
    ------
    ConfigError
        On mismatched shapes, labels outside 0..12, negative or non-integer segment ids, or
        negative or non-finite probabilities.
    """
    params = params or FusionParams()
    xyz, segments, network_labels, network_probs, network_xyz = _validated(
        xyz, segments, network_labels, network_probs, network_xyz, params
    )
    main_plane = _checked_main_plane(main_plane, len(xyz))
    structure = _checked_structure(structure, len(xyz))
    timings: dict[str, float] = {}
    t = time.perf_counter()
    labels, probs = _labels_at_points(xyz, network_xyz, network_labels, network_probs, params)
    timings["transfer"] = time.perf_counter() - t

    t = time.perf_counter()
    segment_ids, seg = _compact_segments(segments)
    ballot = _Ballot(xyz, seg, len(segment_ids), labels, probs, params, totals)
    vote = _vote(ballot, main_plane, structure, timings, t, has_colour)
    return _result(vote, labels, segment_ids, params, timings)


class _Ballot(NamedTuple):
    """What every mode votes on: the points, their segment 0..S-1, S, the network's labels
    and probabilities at the points, and the parameters."""

    xyz: np.ndarray
    seg: np.ndarray
    n_seg: int
    labels: np.ndarray
    probs: np.ndarray | None
    params: FusionParams
    totals: ScanTotals | None


class _Vote(NamedTuple):
    """What a mode's vote decided, per point and per segment (the modes' common return)."""

    fused: np.ndarray
    confidence: np.ndarray
    segment_votes: np.ndarray
    split: np.ndarray
    kept: np.ndarray
    replace: np.ndarray


def _checked_main_plane(main_plane: np.ndarray | None, n: int) -> np.ndarray | None:
    """The main-plane mask as booleans, refused when it does not match the points."""
    if main_plane is None:
        return None
    main_plane = np.asarray(main_plane, dtype=bool)
    if main_plane.shape != (n,):
        raise ConfigError(f"main_plane must have shape ({n},) like xyz, got {main_plane.shape}")
    return main_plane


def _labels_at_points(
    xyz: np.ndarray,
    network_xyz: np.ndarray | None,
    network_labels: np.ndarray,
    network_probs: np.ndarray | None,
    params: FusionParams,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Network labels and probabilities at the segmented points (transferred when the network
    labelled another point set)."""
    if network_xyz is not None:
        return transfer_labels(
            xyz, network_xyz, network_labels, network_probs, neighbours=params.neighbours
        )
    return network_labels.astype(np.int64), network_probs


def _checked_structure(structure: StructureHint | None, n: int) -> StructureHint | None:
    """The structure reading as (int64 classes, float64 confidences), refused when it does
    not match the points or names a class that is not one."""
    if structure is None:
        return None
    kind = np.asarray(structure.kind)
    confidence = np.asarray(structure.confidence, dtype=np.float64)
    if kind.shape != (n,) or confidence.shape != (n,):
        raise ConfigError(
            f"structure must give a class and a confidence per point ({n}), got "
            f"{kind.shape} and {confidence.shape}"
        )
    if n and (kind.min() < -1 or kind.max() >= NUM_CLASSES):
        raise ConfigError(f"structure classes must be -1..{NUM_CLASSES - 1}")
    if n and not (np.isfinite(confidence).all() and 0 <= confidence.min() <= confidence.max() <= 1):
        raise ConfigError("structure confidences must lie in [0, 1]")
    return StructureHint(kind.astype(np.int64), confidence)


def _vote(
    ballot: _Ballot,
    main_plane: np.ndarray | None,
    structure: StructureHint | None,
    timings: dict[str, float],
    t: float,
    has_colour: bool = True,
) -> _Vote:
    """Run the mode's vote, timed from ``t`` as 'vote' (the majority modes add 'relabel')."""
    if ballot.params.mode == "evidence":
        vote = _evidence_vote(ballot)
    elif ballot.params.mode == "learned":
        vote = _learned_vote(ballot, main_plane, structure, has_colour)
    else:
        return _majority_vote(ballot, timings, t)
    timings["vote"] = time.perf_counter() - t
    return vote


def _result(
    vote: _Vote,
    labels: np.ndarray,
    segment_ids: np.ndarray,
    params: FusionParams,
    timings: dict[str, float],
) -> FusionResult:
    """The vote summarised per segment and logged once, as the caller's result."""
    seg_shares, seg_first, _ = guard.top_two_shares(vote.segment_votes)
    seg_kept = vote.kept & ~vote.split
    log.info(
        "fusion (%s): %d points, %d segments, %d relabelled, %d segments kept, %d split",
        params.mode,
        len(labels),
        len(segment_ids),
        int(np.count_nonzero(vote.replace & (vote.fused != labels))),
        int(seg_kept.sum()),
        int(vote.split.sum()),
    )
    return FusionResult(
        labels=vote.fused.astype(np.int32),
        confidence=vote.confidence,
        network_labels=labels.astype(np.int32),
        segment_ids=segment_ids,
        segment_label=seg_shares.argmax(axis=1).astype(np.int32),
        segment_share=seg_first.astype(np.float32),
        segment_kept=seg_kept,
        segment_split=vote.split,
        params=params,
        timings=timings,
    )


def _evidence_vote(ballot: _Ballot) -> _Vote:
    """The 'evidence' mode (see :mod:`jointseg.fusion.evidence`) over segment cells."""
    xyz, seg, n_seg, labels, probs, params, _ = ballot
    p = evidence.point_probs(labels, probs)
    split = np.ones(n_seg, dtype=bool) if params.vote_cell_size > 0 else np.zeros(n_seg, bool)
    if split.any():
        unit, n_units = guard.segment_cells(xyz, seg, params.vote_cell_size)
    else:
        unit, n_units = seg, n_seg
    fused, means = evidence.evidence_labels(unit, n_units, labels, p, weight=params.evidence_weight)
    unit_share = means[unit, fused]
    confidence = _confidence(fused, labels, probs, unit_share)
    seg_votes = _votes(seg, n_seg, labels, p if probs is not None else None)
    return _Vote(fused, confidence, seg_votes, split, np.zeros(n_seg, bool), fused != labels)


def _learned_vote(
    ballot: _Ballot,
    main_plane: np.ndarray | None,
    structure: StructureHint | None,
    has_colour: bool = True,
) -> _Vote:
    """The 'learned' mode (see :mod:`jointseg.fusion.learned`): segment, cell and structure
    offers."""
    xyz, seg, n_seg, labels, probs, params, totals = ballot
    p = evidence.point_probs(labels, probs)
    fused, seg_votes = learned.learned_labels(
        xyz,
        seg,
        n_seg,
        labels,
        p,
        threshold=params.flip_threshold,
        min_support=params.min_support if probs is not None else 0.0,
        main_plane=main_plane,
        totals=None
        if totals is None
        else (totals.points, totals.mean_entropy, totals.disagreement),
        structure=structure,
        has_colour=has_colour,
        metric_iou=params.metric_iou,
        classes=None if totals is None else totals.classes,
        seen_fixture_share=params.seen_fixture_share,
    )
    shares = seg_votes / np.maximum(seg_votes.sum(axis=1, keepdims=True), 1e-12)
    confidence = _confidence(fused, labels, probs, _pick(shares, seg, fused))
    none = np.zeros(n_seg, dtype=bool)
    return _Vote(fused, confidence, seg_votes, none, none, fused != labels)


def _majority_vote(ballot: _Ballot, timings: dict[str, float], t: float) -> _Vote:
    """Eq. 6-7 (hard or soft votes), with the impure-segment guard in the guarded modes."""
    xyz, seg, n_seg, labels, probs, params, totals = ballot
    n = len(xyz) if totals is None else totals.points
    soft = params.mode in SOFT_MODES
    vote_probs = probs if soft else None
    seg_votes = _votes(seg, n_seg, labels, vote_probs)
    seg_shares, seg_first, seg_second = guard.top_two_shares(seg_votes)
    split = np.zeros(n_seg, dtype=bool)
    unit, n_units = seg, n_seg
    shares, first, second = seg_shares, seg_first, seg_second
    guarded = params.mode in GUARDED_MODES
    impure = np.zeros(n_seg, dtype=bool)
    if guarded:
        impure = guard.impure(
            np.bincount(seg, minlength=n_seg), seg_first, seg_second, n_points=n, params=params
        )
        if params.guard_cell_size > 0 and impure.any():
            split = impure
            unit, n_units = guard.split_into_cells(xyz, seg, split, params.guard_cell_size)
            shares, first, second = guard.top_two_shares(_votes(unit, n_units, labels, vote_probs))
    timings["vote"] = time.perf_counter() - t

    t = time.perf_counter()
    majority = shares.argmax(axis=1)
    # eq. 7: a label with less than the ratio threshold of its unit's votes becomes L_max
    replace = shares[unit, labels] < params.ratio_threshold
    kept_units = np.zeros(n_units, dtype=bool)
    if guarded:
        # cells (or segments) without a clear winner keep the network labels; with no cells to
        # split into, so do all impure segments
        kept_units = (first - second) < params.guard_min_margin
        if params.guard_cell_size == 0:
            kept_units |= impure
        replace &= ~kept_units[unit]
    if params.mode != "paper" and probs is not None and params.min_support > 0:
        # never relabel a point to a class the network ruled out for it
        target = majority[unit]
        replace &= np.take_along_axis(probs, target[:, None], axis=1)[:, 0] >= params.min_support
    fused = np.where(replace, majority[unit], labels)
    confidence = _confidence(fused, labels, probs, shares[unit, fused])
    timings["relabel"] = time.perf_counter() - t
    return _Vote(fused, confidence, seg_votes, split, kept_units[:n_seg], replace)


def _votes(
    unit: np.ndarray, n_units: int, labels: np.ndarray, probs: np.ndarray | None
) -> np.ndarray:
    """Label histogram (eq. 6) per unit: point counts, or summed probabilities when given."""
    if probs is None:
        return label_histogram(unit, n_units, labels, NUM_CLASSES).astype(np.float64)
    return group_sums(unit, n_units, probs)


def _confidence(
    fused: np.ndarray, labels: np.ndarray, probs: np.ndarray | None, unit_share: np.ndarray
) -> np.ndarray:
    """Mean of the point's own support for its fused label and its unit's vote share."""
    if probs is None:
        own = (fused == labels).astype(np.float64)
    else:
        own = _pick(probs, np.arange(len(fused)), fused)
    mean = np.add(own, unit_share, dtype=np.float64)
    mean *= 0.5
    return mean.astype(np.float32)


def _compact_segments(segments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`compact_ids` of the (non-negative) segment ids, at once where they already run
    0..S-1 without a gap (as the geometry numbers them)."""
    if len(segments) and not (np.bincount(segments) > 0).all():
        return compact_ids(segments)
    return np.arange(int(segments.max()) + 1 if len(segments) else 0), segments


def _pick(table: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """``table[rows, cols]``, gathered from the flat array (faster for a C-contiguous one)."""
    if not table.flags.c_contiguous:
        return table[rows, cols]
    return np.take(table.reshape(-1), rows * table.shape[1] + cols)


def _validated(
    xyz: np.ndarray,
    segments: np.ndarray,
    network_labels: np.ndarray,
    network_probs: np.ndarray | None,
    network_xyz: np.ndarray | None,
    params: FusionParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Check shapes, dtypes and ranges once, naming the argument and the value."""
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ConfigError(f"xyz must have shape (N, 3), got {xyz.shape}")
    n = len(xyz)
    segments = np.asarray(segments)
    if segments.shape != (n,):
        raise ConfigError(f"segments must have shape ({n},) like xyz, got {segments.shape}")
    if n and not np.issubdtype(segments.dtype, np.integer):
        raise ConfigError(f"segments must be integer ids, got dtype {segments.dtype}")
    if n and segments.min() < 0:
        raise ConfigError(f"segment ids must be non-negative, got {int(segments.min())}")
    segments = segments.astype(np.int64, copy=False)
    if network_xyz is not None:
        network_xyz = np.asarray(network_xyz, dtype=np.float64)
        if network_xyz.ndim != 2 or network_xyz.shape[1] != 3 or len(network_xyz) == 0:
            raise ConfigError(f"network_xyz must have shape (M, 3), M > 0, got {network_xyz.shape}")
    m = n if network_xyz is None else len(network_xyz)
    where = "network_xyz" if network_xyz is not None else "xyz"
    network_labels = np.asarray(network_labels)
    if network_labels.shape != (m,):
        raise ConfigError(
            f"network_labels must have shape ({m},) like {where}, got {network_labels.shape}"
        )
    if m and not np.issubdtype(network_labels.dtype, np.integer):
        raise ConfigError(f"network_labels must be integers, got dtype {network_labels.dtype}")
    if m and (network_labels.min() < 0 or network_labels.max() >= NUM_CLASSES):
        bad = network_labels[(network_labels < 0) | (network_labels >= NUM_CLASSES)][0]
        raise ConfigError(f"network_labels must be class indices 0..{NUM_CLASSES - 1}, got {bad}")
    if network_probs is not None:
        network_probs = np.asarray(network_probs, dtype=np.float32)
        if network_probs.shape != (m, NUM_CLASSES):
            raise ConfigError(
                f"network_probs must have shape ({m}, {NUM_CLASSES}), got {network_probs.shape}"
            )
        # min >= 0 fails on NaN and -inf, max < inf on +inf: finite and non-negative, without
        # a boolean array the size of the probabilities
        if m and not (network_probs.min() >= 0 and network_probs.max() < np.inf):
            raise ConfigError("network_probs must be finite and non-negative")
    return xyz, segments, network_labels, network_probs, network_xyz
