"""Geometry stage benchmark: our segmentation vs a baseline of open3d's own primitives.

Prints, for a 1 M-point synthetic room on this machine: our time per step and in total, the
process's peak memory after our run, the same steps done with open3d primitives on the same
points (segment_plane per box-face set, cluster_dbscan for the Euclidean clusters, a
straightforward queue-based colour region growing), the speed ratio, and how our total time
grows from 250 k to 4 M points.

    .venv/bin/python bench/geometry.py [--points 1000000] [--sizes 250000,500000,...]
"""

from __future__ import annotations

import argparse
import collections
import time

import numpy as np
import open3d as o3d
from helpers.measure import peak_rss_mb
from helpers.report import header

from jointseg.geometry import segment
from jointseg.geometry.params import ResolvedGeometryParams
from jointseg.metrics import segment_purity
from jointseg.scan import Scan
from jointseg.synth import make_room

FACES = ((0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1))


def baseline(scan: Scan, p: ResolvedGeometryParams) -> tuple[np.ndarray, dict[str, float]]:
    """The same three steps with open3d primitives on every point, thresholds as ours."""
    timings: dict[str, float] = {}
    t = time.perf_counter()
    xyz = scan.xyz
    n = len(xyz)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    plane_id = np.full(n, -1)
    for i, (axis, side) in enumerate(FACES):
        value = hi[axis] if side else lo[axis]
        face = np.flatnonzero(np.abs(xyz[:, axis] - value) < p.face_distance)
        if len(face) < 3:
            continue
        # open3d's stub names sequences only; its binding takes index arrays as they are (a
        # list would add its own time to the baseline's)
        sub = cloud.select_by_index(face)  # type: ignore[arg-type]
        _, inliers = sub.segment_plane(
            distance_threshold=p.plane_distance, ransac_n=3, num_iterations=p.ransac_iterations
        )
        plane_id[face[np.asarray(inliers)]] = i
    timings["planes (segment_plane)"] = time.perf_counter() - t

    t = time.perf_counter()
    rest = np.flatnonzero(plane_id < 0)
    rest_cloud = cloud.select_by_index(rest)  # type: ignore[arg-type]
    labels = np.asarray(rest_cloud.cluster_dbscan(eps=p.cluster_distance, min_points=1))
    groups = plane_id.copy()
    groups[rest] = 6 + labels
    timings["clusters (cluster_dbscan)"] = time.perf_counter() - t

    t = time.perf_counter()
    regions = _region_growing(cloud, scan.rgb, groups, p)
    timings["region growing (queue)"] = time.perf_counter() - t
    return regions, timings


def _region_growing(
    cloud: o3d.geometry.PointCloud,
    rgb: np.ndarray | None,
    groups: np.ndarray,
    p: ResolvedGeometryParams,
) -> np.ndarray:
    """Textbook RegionGrowingRGB: a seed queue with a KD-tree radius query per point, then
    merging of neighbouring regions with close mean colours, then of regions that are too
    small into the neighbour they touch most. Raw colours, thresholds scaled to their noise."""
    tree = o3d.geometry.KDTreeFlann(cloud)
    points = np.asarray(cloud.points)
    colour = np.zeros((len(points), 3)) if rgb is None else rgb.astype(np.float64)
    noise = _raw_colour_noise(tree, points, colour)
    point_thr = 2.5 * noise if rgb is not None else np.inf
    region_thr = 4.0 * noise if rgb is not None else np.inf
    region = np.full(len(points), -1)
    contacts: collections.Counter[tuple[int, int]] = collections.Counter()
    current = 0
    for seed in range(len(points)):
        if region[seed] >= 0:
            continue
        region[seed] = current
        queue = collections.deque([seed])
        while queue:
            i = queue.popleft()
            _, idx, _ = tree.search_hybrid_vector_3d(points[i], p.cluster_distance, p.neighbours)
            for j in idx:
                if region[j] >= 0:
                    if region[j] != current:
                        contacts[(current, int(region[j]))] += 1
                    continue
                if groups[j] == groups[i] and np.linalg.norm(colour[j] - colour[i]) < point_thr:
                    region[j] = current
                    queue.append(j)
        current += 1
    # merge neighbouring regions of one group with close mean colours (union-find)
    parent = list(range(current))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    sizes = np.bincount(region, minlength=current)
    means = (
        np.column_stack(
            [np.bincount(region, weights=colour[:, c], minlength=current) for c in range(3)]
        )
        / np.maximum(sizes, 1)[:, None]
    )
    first_point = np.full(current, -1)
    first_point[region[::-1]] = np.arange(len(region))[::-1]
    for a, b in contacts:
        same_group = groups[first_point[a]] == groups[first_point[b]]
        if same_group and np.linalg.norm(means[a] - means[b]) < region_thr:
            parent[find(a)] = find(b)
    merged = np.array([find(r) for r in range(current)])
    region = merged[region]
    # small regions join the neighbour they touch most
    sizes = np.bincount(region, minlength=current)
    best: dict[int, tuple[int, int]] = {}
    for (a, b), count in contacts.items():
        ra, rb = merged[a], merged[b]
        for small, other in ((ra, rb), (rb, ra)):
            if small != other and sizes[small] < p.min_region_points:
                if count > best.get(small, (-1, 0))[1]:
                    best[small] = (other, count)
    target = np.arange(current)
    for small, (other, _) in best.items():
        target[small] = other
    return target[region]


def _raw_colour_noise(
    tree: o3d.geometry.KDTreeFlann, points: np.ndarray, colour: np.ndarray
) -> float:
    rng = np.random.default_rng(0)
    diffs = []
    for i in rng.choice(len(points), size=min(5000, len(points)), replace=False):
        _, idx, _ = tree.search_knn_vector_3d(points[i], 2)
        diffs.append(np.linalg.norm(colour[idx[1]] - colour[i]))
    return float(np.median(diffs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--sizes", default="250000,500000,1000000,2000000,4000000")
    parser.add_argument("--no-baseline", action="store_true")
    args = parser.parse_args()
    header()

    scan = make_room(0, points=args.points)
    assert scan.labels is not None  # synthetic rooms are labelled
    start_rss = peak_rss_mb()
    t = time.perf_counter()
    ours = segment(scan)
    total = time.perf_counter() - t
    ours_rss = peak_rss_mb()
    print(f"# geometry benchmark, {len(scan):,} points (make_room seed 0), {time.strftime('%F')}")
    print()
    print("| step | ours (s) |")
    print("|---|---|")
    for name, seconds in ours.timings.items():
        print(f"| {name} | {seconds:.2f} |")
    print(f"| **total** | **{total:.2f}** |")
    print()
    print(
        f"segments {ours.n_segments}, main planes {len(ours.planes)}, "
        f"purity {segment_purity(scan.labels, ours.segments):.4f}"
    )
    print(
        f"peak RSS of the process after our run: {ours_rss:.0f} MB "
        f"(before it, with the scan generated: {start_rss:.0f} MB)"
    )

    if not args.no_baseline:
        t = time.perf_counter()
        base_regions, base_timings = baseline(scan, ours.params)
        base_total = time.perf_counter() - t
        print()
        print("| baseline step (open3d primitives, same thresholds) | seconds |")
        print("|---|---|")
        for name, seconds in base_timings.items():
            print(f"| {name} | {seconds:.2f} |")
        print(f"| **total** | **{base_total:.2f}** |")
        print()
        print(
            f"baseline segments {len(np.unique(base_regions))}, purity "
            f"{segment_purity(scan.labels, base_regions):.4f}"
        )
        print(f"**speed-up: {base_total / total:.1f}x** (baseline total / our total)")

    print()
    print("| points | ours (s) | µs per point | vs smallest |")
    print("|---|---|---|---|")
    first = None
    for size in (int(s) for s in args.sizes.split(",")):
        room = make_room(0, points=size)
        t = time.perf_counter()
        segment(room)
        seconds = time.perf_counter() - t
        per_point = seconds / size * 1e6
        first = first or per_point
        print(f"| {size:,} | {seconds:.2f} | {per_point:.2f} | {per_point / first:.2f} |")


if __name__ == "__main__":
    main()
