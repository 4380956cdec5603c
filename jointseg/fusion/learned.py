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

This module is the vote itself; the offers and their features are in :mod:`.offers`, the
model read and evaluated in :mod:`.tree_runtime`, the thresholds in :mod:`.thresholds`.
"""

from __future__ import annotations

import numpy as np

from jointseg.classes import CLASS_INDEX
from jointseg.fusion.offers import (
    FEATURES,
    StructureHint,
    _logit,
    _workers,
    vote_offers,
)
from jointseg.fusion.thresholds import ClassTally, offer_thresholds
from jointseg.fusion.tree_runtime import TreeEnsemble, shipped_model

#: A wall fixture the network sees keeps its label against a wall that only the structure
#: reading offers: the network's soft share of the fixture in the point's cell is above this
#: (:func:`seen_fixtures`; 1 turns the rule off).
SEEN_FIXTURE_SHARE = 0.7


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
