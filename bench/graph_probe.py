"""The graph step that issue 13 asked to measure, and a grid over its weights on the tuning rooms.

A CRF whose nodes are the cells of the segments (a segment cut by cubes): unaries are the
network's mean log-probabilities in each cell, pairwise terms tie a cell to its segment (weight
a, the segment's size-weighted mean posterior) and to the cells touching it (weight b, any
segment); a few mean-field sweeps give cell posteriors Q, and a point takes
argmax log p_i(c) + w log Q_cell(c) among classes the network gave it at least min_support.
Cells and not points: a room has ~10^4 cells, so a sweep is a few sparse products.

It did not beat the learned vote on the tuning rooms (CHANGELOG.md, 0.13.0, the graph step),
so it lives here and not in the library. Prints mean / worst gain (mIoU points) per setting on
the real tuning rooms labelled by each network and on the synthetic calibration rooms (bundled
RandLA-Net), next to the learned vote.

    .venv/bin/python bench/graph_probe.py \\
        --networks dgcnn:../shared/models/dgcnn_s3dis/model_6.t7 randlanet
"""

from __future__ import annotations

import argparse
import itertools
import logging

import numpy as np
from helpers.inputs import AREA6, M6, WEAK
from helpers.report import header
from helpers.scans import calibration_rooms, geometry_output, load_items, network_output
from scipy import sparse
from scipy.spatial import cKDTree

from jointseg.fusion import FusionParams, fuse
from jointseg.fusion.evidence import EPS
from jointseg.fusion.guard import segment_cells
from jointseg.fusion.offers import segment_label_sums
from jointseg.metrics import evaluate

#: Neighbours looked up per cell centroid (the graph's degree bound).
NEIGHBOURS = 12


def _softmax(x: np.ndarray) -> np.ndarray:
    x = x - x.max(axis=1, keepdims=True)
    np.exp(x, out=x)
    x /= x.sum(axis=1, keepdims=True)
    return x


def cell_adjacency(centroids: np.ndarray, radius: float) -> sparse.csr_matrix:
    """Row-normalised adjacency of cells whose centroids lie within ``radius`` of each other."""
    n = len(centroids)
    if n < 2:
        return sparse.csr_matrix((n, n), dtype=np.float32)
    k = min(NEIGHBOURS + 1, n)
    dist, idx = cKDTree(centroids).query(centroids, k=k, distance_upper_bound=radius, workers=-1)
    rows = np.repeat(np.arange(n), k - 1)
    cols = idx[:, 1:].ravel()
    keep = cols < n
    rows, cols = rows[keep], cols[keep]
    w = sparse.csr_matrix(
        (np.ones(len(rows), np.float32), (rows, cols)), shape=(n, n), dtype=np.float32
    )
    w = w.maximum(w.T)
    deg = np.asarray(w.sum(axis=1)).ravel()
    inv = np.where(deg > 0, 1.0 / np.maximum(deg, 1e-12), 0.0).astype(np.float32)
    return sparse.diags(inv) @ w


def mean_field(
    unary: np.ndarray,
    unit_seg: np.ndarray,
    unit_size: np.ndarray,
    adjacency: sparse.csr_matrix,
    *,
    segment_weight: float,
    neighbour_weight: float,
    iterations: int,
) -> np.ndarray:
    """Cell posteriors Q (U x C): softmax(unary + a * segment mean of Q + b * neighbour mean of Q).

    The segment mean is weighted by cell size, so a segment speaks with the voice of its points;
    the neighbour mean is over touching cells of any segment (the smoothing a CRF adds).
    """
    q = _softmax(unary.copy())
    n_seg = int(unit_seg.max()) + 1 if len(unit_seg) else 0
    size = unit_size.astype(np.float64)
    seg_size = np.bincount(unit_seg, weights=size, minlength=n_seg)
    for _ in range(iterations):
        sums = segment_label_sums(unit_seg, n_seg, q * size[:, None])
        seg_mean = sums / np.maximum(seg_size, 1e-12)[:, None]
        message = segment_weight * seg_mean[unit_seg]
        if neighbour_weight:
            message = message + neighbour_weight * (adjacency @ q)
        q = _softmax(unary + message)
    return q


def graph_labels(
    xyz: np.ndarray,
    seg: np.ndarray,
    labels: np.ndarray,
    p: np.ndarray,
    *,
    cell_size: float,
    segment_weight: float,
    neighbour_weight: float,
    point_weight: float,
    iterations: int = 5,
    min_support: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Labels after the graph step, the cell of every point and the cell posteriors.

    A point takes argmax_c log p_i(c) + w log Q_cell(c), but only a class the network gave it at
    least ``min_support``; elsewhere it keeps the network's label.
    """
    unit, n_units = segment_cells(xyz, seg, cell_size)
    size = np.bincount(unit, minlength=n_units).astype(np.float64)
    sums = segment_label_sums(unit, n_units, p)
    mean = sums / np.maximum(size, 1)[:, None]
    centroids = (
        np.stack(
            [np.bincount(unit, weights=xyz[:, d], minlength=n_units) for d in range(3)], axis=1
        )
        / np.maximum(size, 1)[:, None]
    )
    unit_seg = np.zeros(n_units, dtype=np.int64)
    unit_seg[unit] = seg
    adjacency = cell_adjacency(centroids, 2.0 * cell_size)
    q = mean_field(
        np.log(mean + EPS),
        unit_seg,
        size,
        adjacency,
        segment_weight=segment_weight,
        neighbour_weight=neighbour_weight,
        iterations=iterations,
    )
    cell_best = q.argmax(axis=1)
    fused = labels.copy()
    cand = np.flatnonzero(cell_best[unit] != labels)
    if len(cand):
        score = np.log(p[cand] + EPS) + point_weight * np.log(q[unit[cand]] + EPS)
        best = score.argmax(axis=1)
        ok = p[cand, best] >= min_support
        fused[cand[ok]] = best[ok]
    return fused, unit, q


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--networks", nargs="+", default=[M6, WEAK])
    parser.add_argument("--segment-weight", type=float, nargs="+", default=[0.0, 2.0, 4.0, 8.0])
    parser.add_argument("--neighbour-weight", type=float, nargs="+", default=[0.0, 1.0, 2.0])
    parser.add_argument("--point-weight", type=float, nargs="+", default=[0.4, 0.7, 1.0])
    parser.add_argument("--cell", type=float, nargs="+", default=[0.3])
    parser.add_argument("--split", default="tune", choices=["tune", "judge"])
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    real = [i for i in load_items([str(AREA6)], 10, (0, 0, 0)) if i.split == args.split]
    synth = calibration_rooms(10, 2, 100_000)
    predictors: dict = {}
    groups = {n.rpartition("/")[2]: [(i, n) for i in real] for n in args.networks}
    groups["synthetic"] = [(i, WEAK) for i in synth]
    data = {}
    for gname, pairs in groups.items():
        rows = []
        for item, spec in pairs:
            labels, probs = network_output(spec, item, predictors)
            g = geometry_output("default", item)
            gt = item.scan.labels
            assert gt is not None  # tuning scans are labelled
            net = evaluate(gt, labels).miou or 0.0
            learned = fuse(
                item.scan.xyz,
                g["segments"],
                labels,
                probs,
                FusionParams(),
                main_plane=g["plane_id"] >= 0,
            ).labels
            rows.append(
                (
                    item,
                    labels,
                    probs,
                    g["segments"].astype(np.int64),
                    gt,
                    net,
                    (evaluate(gt, learned).miou or 0.0) - net,
                )
            )
        data[gname] = rows
        gains = np.array([r[6] for r in rows]) * 100
        print(f"{gname}: learned {gains.mean():+.2f} / {gains.min():+.2f}", flush=True)
    support = FusionParams().min_support
    for cell, a, b, w in itertools.product(
        args.cell, args.segment_weight, args.neighbour_weight, args.point_weight
    ):
        parts = []
        for gname, rows in data.items():
            held: list[float] = []
            for item, labels, probs, seg, gt, net, _ in rows:
                fused, _, _ = graph_labels(
                    item.scan.xyz,
                    seg,
                    labels,
                    probs,
                    cell_size=cell,
                    segment_weight=a,
                    neighbour_weight=b,
                    point_weight=w,
                    min_support=support,
                )
                held.append((evaluate(gt, fused).miou or 0.0) - net)
            points = np.array(held) * 100
            parts.append(f"{gname} {points.mean():+.2f} / {points.min():+.2f}")
        print(f"cell {cell} a {a} b {b} w {w}: " + " | ".join(parts), flush=True)


if __name__ == "__main__":
    main()
