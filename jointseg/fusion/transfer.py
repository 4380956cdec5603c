"""Carry network labels from the point set the network labelled to the segmented points.

The paper queries, for every point of the geometric segmentation, its K nearest points in the
network's result (§2.3): the network may have labelled a sub-sampled or otherwise different
cloud. Memory stays linear in N: neighbour votes are counted in chunks of rows.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from jointseg.classes import NUM_CLASSES
from jointseg.grouping import majority_label

#: Rows per chunk when counting neighbour votes (bounds the (rows, K, 13) temporaries).
CHUNK = 131_072


def transfer_labels(
    xyz: np.ndarray,
    network_xyz: np.ndarray,
    network_labels: np.ndarray,
    network_probs: np.ndarray | None,
    *,
    neighbours: int = 1,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Labels (and probabilities) of every point of ``xyz`` from its K nearest network points.

    Parameters
    ----------
    xyz : ndarray of shape (N, 3), metres
        The segmented points.
    network_xyz : ndarray of shape (M, 3), metres
        The points the network labelled.
    network_labels : ndarray of shape (M,), int
        Class indices 0..12.
    network_probs : ndarray of shape (M, 13), optional
        Class probabilities.
    neighbours : int
        K. Each point takes the majority label of its K nearest network points, ties going to
        the nearer point's label, and the mean of their probabilities.

    Returns
    -------
    labels : ndarray of shape (N,), int64
    probs : ndarray of shape (N, 13), float32, or None
    """
    k = min(neighbours, len(network_xyz))
    _, idx = cKDTree(network_xyz).query(xyz, k=k, workers=-1)
    idx = np.asarray(idx).reshape(len(xyz), k)
    if k == 1:
        nearest = idx[:, 0]
        probs = None if network_probs is None else network_probs[nearest].astype(np.float32)
        return network_labels[nearest].astype(np.int64), probs
    labels = np.empty(len(xyz), dtype=np.int64)
    probs_out = None if network_probs is None else np.empty((len(xyz), NUM_CLASSES), np.float32)
    # nearer neighbours weigh a little more, so a tied vote goes to the nearest label
    rank_weight = 1.0 + (k - np.arange(k)) / (k * 1000.0)
    for start in range(0, len(xyz), CHUNK):
        block = idx[start : start + CHUNK]
        rows = len(block)
        labels[start : start + rows] = majority_label(
            np.repeat(np.arange(rows), k),
            rows,
            network_labels[block].reshape(-1),
            NUM_CLASSES,
            weights=np.tile(rank_weight, rows),
        )
        if probs_out is not None and network_probs is not None:
            probs_out[start : start + rows] = network_probs[block].mean(axis=1)
    return labels, probs_out
