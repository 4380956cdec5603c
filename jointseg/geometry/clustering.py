"""Euclidean cluster extraction (§2.2.2) and colour region growing (§2.2.3) on one shared
neighbour graph.

Both are connected components of a thresholded k-nearest-neighbour graph, which is what PCL's
EuclideanClusterExtraction and RegionGrowingRGB compute with their seed queues: a point joins
when it is within the distance threshold of a member (and, for region growing, its colour is
within the point colour threshold of that member). Building the graph once with a KD-tree and
labelling components with scipy replaces the per-point queue with array operations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from jointseg.grouping import compact_ids, sorted_distinct
from jointseg.voxels import cell_means

#: Edges handled at a time by the per-edge arithmetic: temporaries of a few megabytes stay in
#: the cache and in memory already mapped, where whole-graph ones (tens of millions of edges on
#: a big scan) fault in fresh pages on every step.
EDGE_CHUNK = 1 << 18


def edge_chunks(m: int) -> range:
    """Start of each chunk of :data:`EDGE_CHUNK` edges among ``m``."""
    return range(0, m, EDGE_CHUNK)


@dataclass(frozen=True)
class NeighbourGraph:
    """Directed edges ``src -> dst`` to each point's k nearest neighbours within a radius.

    ``local`` is each point's distance to its nearest distinct neighbour (its local spacing),
    which lets thresholds follow density where a scanner's density falls with range.
    """

    n: int
    src: np.ndarray
    dst: np.ndarray
    dist: np.ndarray
    local: np.ndarray
    _masks: dict[tuple[float, float], np.ndarray] = field(
        default_factory=dict, repr=False, compare=False
    )

    def within(self, distance: float, *, adaptive: float = 0.0) -> np.ndarray:
        """Mask of edges shorter than ``distance`` or, when ``adaptive`` > 0, shorter than
        ``adaptive`` times the larger local spacing of their two ends.

        Masks are kept per threshold: smoothing, clustering and region growing ask for the
        same one on every edge of the scan. Treat the returned array as read-only.
        """
        key = (float(distance), float(adaptive))
        if key not in self._masks:
            if adaptive <= 0:
                mask = self.dist < distance
            else:
                mask = np.empty(len(self.dist), dtype=bool)
                for s in edge_chunks(len(mask)):
                    e = slice(s, s + EDGE_CHUNK)
                    scale = np.maximum(self.local[self.src[e]], self.local[self.dst[e]])
                    scale *= adaptive
                    np.less(self.dist[e], np.maximum(scale, distance, out=scale), out=mask[e])
            mask.setflags(write=False)
            self._masks[key] = mask
        return self._masks[key]


def neighbour_graph(tree: cKDTree, xyz: np.ndarray, *, k: int, radius: float) -> NeighbourGraph:
    """Query each point's ``k`` nearest neighbours within ``radius`` (metres) once."""
    dist, idx = tree.query(xyz, k=k + 1, distance_upper_bound=radius, workers=-1)
    n = len(xyz)
    valid = idx < n
    valid &= idx != np.arange(n)[:, None]
    # a missing neighbour's distance is inf and a point's own is 0, so the positive distances
    # are those of valid neighbours; reduced over transposed copies of a few rows at a time, as
    # a row of k + 1 is too short for numpy's reduction to run fast
    local = np.empty(n)
    rows = max(1, EDGE_CHUNK // (k + 1))
    for s in range(0, n, rows):
        positive = dist[s : s + rows].T.copy()  # a copy even of a single row
        positive[positive <= 0] = np.inf
        np.minimum.reduce(positive, axis=0, out=local[s : s + rows])
    local[~np.isfinite(local)] = radius
    edges = np.flatnonzero(valid)  # row-major, so the edges come sorted by src
    src = edges // (k + 1)
    dst = np.take(idx.reshape(-1), edges).astype(np.int64, copy=False)
    return NeighbourGraph(n, src, dst, np.take(dist.reshape(-1), edges), local)


def compact(labels: np.ndarray) -> np.ndarray:
    """Renumber labels to 0..L-1 keeping their order (:func:`jointseg.grouping.compact_ids`),
    so region and cluster ids stay dense after merges."""
    return compact_ids(labels)[1]


def components(n: int, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Connected-component label (0..C-1) of each of ``n`` nodes given undirected edges.

    Components are numbered in the order of their lowest node, whatever the order of the
    edges; edges sorted by ``src`` (the graph's own, and every subset of them) go straight into
    a CSR matrix without the COO conversion's sort.
    """
    if is_sorted(src):
        graph = csr_matrix((np.ones(len(src)), dst, row_pointers(src, n)), shape=(n, n))
    else:
        graph = coo_matrix((np.ones(len(src), dtype=np.int8), (src, dst)), shape=(n, n)).tocsr()
    _, labels = connected_components(graph, directed=False)
    return labels.astype(np.int64)


def is_sorted(src: np.ndarray) -> bool:
    """Whether ``src`` never decreases (the graph's edges and every subset of them)."""
    return len(src) < 2 or bool(np.all(src[1:] >= src[:-1]))


def row_pointers(src: np.ndarray, n: int) -> np.ndarray:
    """CSR row pointers of edges sorted by ``src`` (``n`` rows)."""
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(src, minlength=n), out=indptr[1:])
    return indptr


def colour_close(colour: np.ndarray, a: np.ndarray, b: np.ndarray, threshold: float) -> np.ndarray:
    """``colour_distance(colour, a, b) < threshold``, edge chunk by edge chunk."""
    close = np.empty(len(a), dtype=bool)
    for s in edge_chunks(len(a)):
        e = slice(s, s + EDGE_CHUNK)
        np.less(colour_distance(colour, a[e], b[e]), threshold, out=close[e])
    return close


def colour_distance(colour: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(colour[a] - colour[b], axis=1)`` to the bit, for 3-channel ``colour``.

    Rows gathered with ``np.take`` and the squares summed in norm's order, ``(r + g) + b``,
    cost a fifth of the fancy-indexed version on millions of edges.
    """
    if colour.ndim != 2 or colour.shape[1] != 3:
        return np.linalg.norm(colour[a] - colour[b], axis=1)
    if len(a) > EDGE_CHUNK:
        first = colour_distance(colour, a[:EDGE_CHUNK], b[:EDGE_CHUNK])
        out = np.empty(len(a), dtype=first.dtype)
        out[:EDGE_CHUNK] = first
        for s in edge_chunks(len(a))[1:]:
            e = slice(s, s + EDGE_CHUNK)
            out[e] = colour_distance(colour, a[e], b[e])
        return out
    diff = np.take(colour, a, axis=0)
    diff -= np.take(colour, b, axis=0)
    if not np.issubdtype(diff.dtype, np.inexact):
        diff = diff.astype(np.float64)  # as norm does, after the subtraction
    diff *= diff
    total = diff[:, 0] + diff[:, 1]
    total += diff[:, 2]
    return np.sqrt(total, out=total)


def euclidean_clusters(
    graph: NeighbourGraph, member: np.ndarray, *, tolerance: float, adaptive: float = 0.0
) -> np.ndarray:
    """Cluster the points where ``member`` is true; others get -1.

    Parameters
    ----------
    member : ndarray of shape (N,), bool
        Points to cluster (the scan minus its main planes).
    tolerance : float
        d_th, metres: neighbours closer than this belong to the same cluster.
    adaptive : float
        When > 0, sparse regions use ``adaptive`` x local spacing where that is larger.
    """
    keep = member[graph.src] & member[graph.dst] & graph.within(tolerance, adaptive=adaptive)
    labels = components(graph.n, graph.src[keep], graph.dst[keep])
    out = np.full(graph.n, -1, dtype=np.int64)
    out[member] = compact(labels[member])
    return out


def smooth_colours(graph: NeighbourGraph, rgb: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Average each point's colour with its neighbours along ``edges`` (a mask over the graph).

    Texture and sensor noise make single-point colour differences nearly as large as the
    difference between a door and its wall; the neighbourhood mean keeps the contrast between
    surfaces while cutting the noise by about the square root of the neighbour count.
    """
    src, dst = graph.src[edges], graph.dst[edges]
    weights = np.ones(len(src), dtype=np.float32)
    shape = (graph.n, graph.n)
    if is_sorted(src):
        # the graph's edges come sorted by src: the CSR matrix the COO conversion makes, built
        # directly (its sum_duplicates sorts each row's columns as the conversion does, so the
        # float32 sums run in the same order)
        adjacency = csr_matrix((weights, dst, row_pointers(src, graph.n)), shape=shape)
        adjacency.sum_duplicates()
    else:
        adjacency = coo_matrix((weights, (src, dst)), shape=shape).tocsr()
    colour = rgb.astype(np.float32)
    total = adjacency @ colour + colour
    count = np.bincount(src, minlength=graph.n).astype(np.float32) + 1.0
    return total / count[:, None]


def region_grow_rgb(
    graph: NeighbourGraph,
    rgb: np.ndarray | None,
    groups: np.ndarray,
    *,
    distance: float,
    point_threshold: float | None,
    region_threshold: float | None,
    adaptive: float = 0.0,
    normals: np.ndarray | None = None,
    max_normal_deg: float = 90.0,
) -> np.ndarray:
    """Colour region growing inside each group (a main plane or a Euclidean cluster).

    Neighbours within ``distance`` whose colours differ by less than ``point_threshold`` join
    the same region; then neighbouring regions of one group whose mean colours differ by less
    than ``region_threshold`` are merged. Without colour the groups are returned as regions.

    Returns
    -------
    ndarray of shape (N,), int64
        Region id (0..R-1) of every point.
    """
    near = graph.within(distance, adaptive=adaptive)
    same = np.empty(len(near), dtype=bool)
    for s in edge_chunks(len(same)):
        e = slice(s, s + EDGE_CHUNK)
        np.equal(groups[graph.src[e]], groups[graph.dst[e]], out=same[e])
        same[e] &= near[e]
    src, dst = graph.src[same], graph.dst[same]
    if rgb is None or point_threshold is None:
        return compact(groups)
    colour = rgb.astype(np.float32)  # may already be smoothed
    close = colour_close(colour, src, dst, point_threshold)
    if normals is not None and max_normal_deg < 90:
        # a crease (table top to leg, seat to back, lamp to ceiling) stops a region too
        cos = np.abs(np.einsum("ij,ij->i", normals[src], normals[dst]))
        close &= cos > np.cos(np.radians(max_normal_deg))
    regions = components(graph.n, src[close], dst[close])
    if region_threshold is None:
        return regions
    count = int(regions.max()) + 1
    means = cell_means(colour, regions, count)
    pairs = [np.zeros(0, dtype=np.int64)]
    for s in edge_chunks(len(src)):
        a, b = regions[src[s : s + EDGE_CHUNK]], regions[dst[s : s + EDGE_CHUNK]]
        cross = a != b
        pairs.append(a[cross] * count + b[cross])
    keys = sorted_distinct(np.concatenate(pairs))
    if len(keys) == 0:
        return regions
    pa, pb = keys // count, keys % count
    similar = colour_close(means, pa, pb, region_threshold)
    merged = components(count, pa[similar], pb[similar])
    return merged[regions]


def nearest_among(
    tree: cKDTree, xyz: np.ndarray, excluded: np.ndarray, k: int
) -> np.ndarray | None:
    """The ``k`` nearest points outside ``excluded`` (a mask over ``xyz``) of each excluded
    point, nearest first, from ``tree`` over all of ``xyz``: what a tree over the others
    alone would answer, without building it.

    Neighbours are fetched in growing numbers until each point has ``k + 1`` others. Two
    trees may order equally distant points differently, so where any of those ``k + 1``
    distances repeats, None is returned and the caller builds the tree after all.
    """
    query = np.flatnonzero(excluded)
    n, want = len(xyz), k + 1
    if n - len(query) < want:
        return None
    out = np.empty((len(query), want), dtype=np.int64)
    dist = np.empty((len(query), want))
    todo = np.arange(len(query))
    fetch = 2 * want
    while len(todo):
        fetch = min(fetch, n)
        d, i = tree.query(xyz[query[todo]], k=fetch, workers=-1)
        d, i = d.reshape(len(todo), fetch), i.reshape(len(todo), fetch)
        other = ~excluded[i]
        rank = np.cumsum(other, axis=1)
        done = rank[:, -1] >= want
        keep = other[done] & (rank[done] <= want)  # exactly ``want`` per row, in order
        out[todo[done]] = i[done][keep].reshape(-1, want)
        dist[todo[done]] = d[done][keep].reshape(-1, want)
        todo = todo[~done]
        fetch *= 4
    if not np.all(dist[:, 1:] > dist[:, :-1]):
        return None
    return out[:, :k]


def merge_small_regions(
    graph: NeighbourGraph,
    xyz: np.ndarray,
    regions: np.ndarray,
    groups: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    min_points: int,
    rounds: int = 4,
    tree: cKDTree | None = None,
) -> np.ndarray:
    """Merge regions smaller than ``min_points`` into their nearest region.

    A small region joins the neighbouring region it shares most graph edges with, preferring
    one of its own group (main plane or cluster) and a large one; chains of small regions are
    resolved over a few rounds. Small regions with no graph neighbour take the region of the
    nearest point of a large region, again preferring their own group. No point is dropped.
    ``weights`` counts how many scan points each graph node stands for (voxel sizes); ``tree``
    indexes ``xyz`` (the graph's own), so the few points left in small regions need no tree
    of the large regions' points.
    """
    regions = compact(regions)
    for _ in range(rounds):
        sizes = np.bincount(regions, weights=weights)
        small = sizes < min_points
        if not small.any():
            break
        # the edges leaving a small region, found without gathering every edge's two regions
        leaving = np.flatnonzero(small[regions][graph.src])
        src, dst = graph.src[leaving], graph.dst[leaving]
        a, b = regions[src], regions[dst]
        cand = a != b
        if not cand.any():
            break
        count = len(sizes)
        same_group = groups[src[cand]] == groups[dst[cand]]
        keys = (a[cand] * count + b[cand]) * 2 + same_group
        pair_keys, pair_counts = np.unique(keys, return_counts=True)
        same, pair_keys = pair_keys % 2, pair_keys // 2
        pa, pb = pair_keys // count, pair_keys % count
        score = pair_counts + (same.astype(np.int64) << 40) + np.where(small[pb], 0, 1 << 30)
        order = np.lexsort((-score, pa))
        first = np.ones(len(order), dtype=bool)
        first[1:] = pa[order][1:] != pa[order][:-1]
        merged = components(count, pa[order][first], pb[order][first])
        regions = compact(merged[regions])
    sizes = np.bincount(regions, weights=weights)
    small_pts = sizes[regions] < min_points
    if small_pts.any() and (~small_pts).any():
        big_idx = np.flatnonzero(~small_pts)
        k = min(8, len(big_idx))
        nearest = None if tree is None else nearest_among(tree, xyz, small_pts, k)
        if nearest is None:
            _, found = cKDTree(xyz[big_idx]).query(xyz[small_pts], k=k, workers=-1)
            nearest = big_idx[np.asarray(found).reshape(-1, k)]
        same = groups[nearest] == groups[small_pts][:, None]
        pick = np.where(same.any(axis=1), same.argmax(axis=1), 0)
        regions = regions.copy()
        regions[small_pts] = regions[nearest[np.arange(len(pick)), pick]]
        regions = compact(regions)
    return regions
