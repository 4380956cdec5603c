"""The learned vote written plainly, as it was before it was made fast (commit 11aad11): a
reference the fast code must match to the bit.

Row-major sums and entropy, cells renumbered by ``np.unique``, door cells found by
``np.unique(axis=0)``, quantiles by ``np.lexsort``, every tree walked for every row, and the
best offer per point by ``np.lexsort``. Slow, and kept out of the library for that reason.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from jointseg.classes import NUM_CLASSES
from jointseg.fusion import fixtures
from jointseg.fusion.learned import seen_fixtures
from jointseg.fusion.offers import FIXTURE, STRUCTURAL, StructureHint, _logit
from jointseg.fusion.thresholds import ClassTally, offer_thresholds
from jointseg.fusion.tree_runtime import TreeEnsemble
from jointseg.geometry.structure import floor_level


def entropy(probs: np.ndarray) -> np.ndarray:
    """Normalised entropy, row-major float64 blocks of 2**18 rows."""
    n, n_classes = probs.shape
    out = np.empty(n)
    for start in range(0, n, 1 << 18):
        p = np.asarray(probs[start : start + (1 << 18)], dtype=np.float64)
        out[start : start + (1 << 18)] = -(p * np.log(p + 1e-6)).sum(axis=1)
    return out / np.log(n_classes)


def sums(unit: np.ndarray, n_units: int, probs: np.ndarray) -> np.ndarray:
    """Per-unit column sums, one strided column at a time."""
    return np.column_stack(
        [np.bincount(unit, weights=probs[:, c], minlength=n_units) for c in range(probs.shape[1])]
    )


def tally(labels: np.ndarray, probs: np.ndarray) -> ClassTally:
    """The network's class tally, row-major float64 blocks."""
    labels = np.asarray(labels, dtype=np.int64)
    n_classes = probs.shape[1]
    expected = np.zeros(n_classes)
    own = np.empty(len(labels))
    for start in range(0, len(labels), 1 << 18):
        rows = np.asarray(probs[start : start + (1 << 18)], dtype=np.float64)
        expected += rows.sum(axis=0)
        block = labels[start : start + (1 << 18)]
        own[start : start + len(block)] = rows[np.arange(len(block)), block]
    return ClassTally(
        np.bincount(labels, minlength=n_classes).astype(np.float64),
        expected,
        np.bincount(labels, weights=own, minlength=n_classes),
    )


def segment_cells(xyz: np.ndarray, seg: np.ndarray, size: float) -> tuple[np.ndarray, int]:
    """One unit per (segment, aligned cell), numbered by ``np.unique``."""
    cells = np.floor(xyz / size).astype(np.int64)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    ids, unit = np.unique(seg.astype(np.int64) * int(dims.prod()) + keys, return_inverse=True)
    return unit.reshape(-1), len(ids)


def quantiles(group: np.ndarray, n: int, values: np.ndarray, qs: tuple[float, ...]) -> list:
    """Per-group quantiles by ``np.lexsort``."""
    counts = np.bincount(group, minlength=n)
    ordered = values[np.lexsort((values, group))]
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = []
    for q in qs:
        pos = starts + np.floor(q * np.maximum(counts - 1, 0)).astype(np.int64)
        out.append(np.where(counts > 0, ordered[np.minimum(pos, len(values) - 1)], np.nan))
    return out


def pieces(xyz: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected pieces of CELL cells, the cells by ``np.unique(axis=0)``."""
    cells = np.floor(np.asarray(xyz, dtype=np.float64) / fixtures.CELL).astype(np.int64)
    keys, cell_of = np.unique(cells, axis=0, return_inverse=True)
    pairs = cKDTree(keys).query_pairs(np.sqrt(3) + 1e-6, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), (len(keys),) * 2)
    n, piece_of_cell = connected_components(graph, directed=False)
    return piece_of_cell[cell_of.reshape(-1)], int(n)


def extents(xyz: np.ndarray, group: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    """Per piece: extent along its main horizontal direction, height, bottom, count."""
    count = np.bincount(group, minlength=n).astype(np.float64)
    safe = np.maximum(count, 1)
    mean = np.column_stack([np.bincount(group, xyz[:, i], n) / safe for i in range(2)])
    d = xyz[:, :2] - mean[group]
    cov = np.empty((n, 2, 2))
    for i in range(2):
        for j in range(i, 2):
            cov[:, i, j] = cov[:, j, i] = np.bincount(group, d[:, i] * d[:, j], n) / safe
    _, vectors = np.linalg.eigh(cov)
    along = np.einsum("ni,ni->n", d, vectors[group, :, 1])
    lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(lo, group, along)
    np.maximum.at(hi, group, along)
    zlo, zhi = quantiles(group, n, xyz[:, 2], (0.02, 0.98))
    return hi - lo, zhi - zlo, zlo, count


def implausible(xyz: np.ndarray, labels: np.ndarray, cls: int, floor_z: float | None) -> np.ndarray:
    """:func:`fixtures.implausible_doors` (or ``_columns`` for the column class), plainly."""
    out = np.zeros(len(labels), dtype=bool)
    idx = np.flatnonzero(np.asarray(labels) == cls)
    if len(idx) < fixtures.MIN_POINTS:
        return out
    piece, n = pieces(xyz[idx])
    width, height, bottom, count = extents(xyz[idx], piece, n)
    big = count >= fixtures.MIN_POINTS
    if cls == fixtures.COLUMN:
        bad = big & (width > fixtures.MAX_COLUMN_WIDTH)
    else:
        bad = big & (
            (width > fixtures.MAX_WIDTH)
            | ((width > fixtures.LOW_WIDTH) & (height < fixtures.LOW_HEIGHT))
            | (height < fixtures.MIN_HEIGHT)
        )
        if floor_z is not None:
            bad |= big & (bottom > floor_z + fixtures.MAX_FOOT)
    out[idx[bad[piece]]] = True
    return out


def offer_features(
    xyz: np.ndarray,
    seg: np.ndarray,
    n_seg: int,
    labels: np.ndarray,
    probs: np.ndarray,
    *,
    cell_size: float,
    main_plane: np.ndarray | None,
    min_support: float,
    structure: StructureHint | None,
    has_colour: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Offered points, labels, features and the segments' votes, as vote_offers made them."""
    n, n_classes = probs.shape
    labels = np.asarray(labels, dtype=np.int64)
    seg_size = np.bincount(seg, minlength=n_seg).astype(np.float64)
    seg_votes = sums(seg, n_seg, probs)
    seg_soft = seg_votes / np.maximum(seg_size, 1)[:, None]
    hist = np.bincount(seg * n_classes + labels, minlength=n_seg * n_classes)
    seg_hard = hist.reshape(n_seg, n_classes) / np.maximum(seg_size, 1)[:, None]
    cell, n_cells = segment_cells(xyz, seg, cell_size) if cell_size > 0 else (seg, n_seg)
    cell_size_pts = np.bincount(cell, minlength=n_cells).astype(np.float64)
    cell_soft = sums(cell, n_cells, probs) / np.maximum(cell_size_pts, 1)[:, None]
    ent = entropy(probs)
    counts = hist.reshape(n_seg, n_classes)
    majority = np.where(counts.sum(axis=1) > 0, counts.argmax(axis=1), -1)
    scan_entropy, scan_disagreement = float(ent.mean()), float(np.mean(majority[seg] != labels))
    seg_entropy = np.bincount(seg, weights=ent, minlength=n_seg) / np.maximum(seg_size, 1)
    plane_share = (
        np.zeros(n_seg)
        if main_plane is None
        else np.bincount(seg, weights=main_plane.astype(np.float64), minlength=n_seg)
        / np.maximum(seg_size, 1)
    )
    seg_label, cell_label = seg_soft.argmax(axis=1)[seg], cell_soft.argmax(axis=1)[cell]
    by_segment = np.flatnonzero(seg_label != labels)
    by_cell = np.flatnonzero((cell_label != labels) & (cell_label != seg_label))
    point = np.concatenate([by_segment, by_cell])
    offer = np.concatenate([seg_label[by_segment], cell_label[by_cell]])
    from_segment = np.arange(len(point)) < len(by_segment)
    if min_support > 0:
        supported = probs[point, offer] >= min_support
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
    s, c, own = seg[point], cell[point], labels[point]
    floor_z = None if structure is None else floor_level(xyz[:, 2], structure.kind)
    fixture = FIXTURE[labels] & ~implausible(xyz, labels, fixtures.DOOR, floor_z)
    fixture &= ~implausible(xyz, labels, fixtures.COLUMN, None)
    reads_offer = reads_own = np.zeros(len(point))
    if structure is not None:
        kind = np.asarray(structure.kind, dtype=np.int64)
        sure = np.asarray(structure.confidence, dtype=np.float64)[point]
        reads_offer = np.where(kind[point] == offer, sure, 0.0)
        reads_own = np.where(kind[point] == own, sure, 0.0)
    features = np.column_stack(
        [
            _logit(probs[point, own]),
            _logit(probs[point, offer]),
            _logit(seg_soft[s, offer]),
            _logit(seg_soft[s, own]),
            _logit(seg_hard[s, offer]),
            np.log10(seg_size[s] / max(n, 1)),
            seg_entropy[s],
            ent[point],
            _logit(cell_soft[c, offer]),
            _logit(cell_soft[c, own]),
            np.log10(cell_size_pts[c] / np.maximum(seg_size[s], 1)),
            plane_share[s],
            STRUCTURAL[own],
            STRUCTURAL[offer],
            from_segment,
            np.full(len(point), scan_entropy),
            np.full(len(point), scan_disagreement),
            reads_offer,
            reads_own,
            only_structure,
            fixture[point],
            np.full(len(point), float(has_colour)),
        ]
    ).astype(np.float64)
    return point, offer, features, seg_votes


def walk(model: TreeEnsemble, x: np.ndarray) -> np.ndarray:
    """The ensemble's raw score of every row, each tree walked node by node, row by row."""
    x = np.asarray(x, dtype=np.float64)[:, : model.n_features]
    out = np.empty(len(x))
    for i, row in enumerate(x):
        raw = model.base
        for t in range(len(model.feature)):
            node = 0
            while not model.leaf[t][node]:
                go_left = row[model.feature[t][node]] <= model.threshold[t][node]
                node = int(model.left[t][node] if go_left else model.right[t][node])
            raw += model.value[t][node]
        out[i] = raw
    return out


def best(labels: np.ndarray, point: np.ndarray, label: np.ndarray, p: np.ndarray, at) -> np.ndarray:
    """Each point's most probable offer above its threshold, by ``np.lexsort``."""
    fused = np.asarray(labels, dtype=np.int64).copy()
    take = np.flatnonzero(p > at)
    order = take[np.lexsort((-p[take], point[take]))]
    first = np.ones(len(order), dtype=bool)
    first[1:] = point[order][1:] != point[order][:-1]
    chosen = order[first]
    fused[point[chosen]] = label[chosen]
    return fused


def learned_labels(
    model: TreeEnsemble,
    xyz: np.ndarray,
    seg: np.ndarray,
    n_seg: int,
    labels: np.ndarray,
    probs: np.ndarray,
    *,
    threshold: float,
    min_support: float,
    main_plane: np.ndarray | None,
    structure: StructureHint | None,
    has_colour: bool,
    metric_iou: float | str,
    seen_fixture_share: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The learned vote's labels and the segments' votes, plainly (every row walked)."""
    point, offer, features, seg_votes = offer_features(
        xyz,
        seg,
        n_seg,
        labels,
        probs,
        cell_size=model.cell_size,
        main_plane=main_plane,
        min_support=min_support,
        structure=structure,
        has_colour=has_colour,
    )
    p = 1.0 / (1.0 + np.exp(-walk(model, features))) if len(point) else np.zeros(0)
    p = np.where(seen_fixtures(features, offer, seen_fixture_share), 0.0, p)
    at: float | np.ndarray = threshold
    labels = np.asarray(labels, dtype=np.int64)
    if metric_iou == "auto" or float(metric_iou) < 1:
        at = offer_thresholds(tally(labels, probs), labels[point], offer, threshold, metric_iou)
    assert NUM_CLASSES == probs.shape[1]
    return best(labels, point, offer, p, at), seg_votes
