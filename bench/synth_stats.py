"""Compare per-class point shares of synthetic rooms with S3DIS and time the generator.

Usage: ``python bench/synth_stats.py [--points N] [--seeds K]``
"""

from __future__ import annotations

import argparse
from typing import Literal

import numpy as np
from helpers.measure import best_time
from helpers.report import header

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.synth import make_floor, make_room

#: Points per class in S3DIS (RandLA-Net's S3DIS configuration, i.e. the dataset statistics).
S3DIS_COUNTS = np.array(
    [
        3370714, 2856755, 4919229, 318158, 375640, 478001, 974733,
        650464, 791496, 88727, 1284130, 229758, 2272837,
    ],
    dtype=np.float64,
)  # fmt: skip


def shares(shape: Literal["box", "L"], seeds: range, points: int) -> np.ndarray:
    """Per-seed class shares, shape (len(seeds), 13)."""
    out = np.zeros((len(seeds), NUM_CLASSES))
    for i, seed in enumerate(seeds):
        scan = make_room(seed, points=points, shape=shape)
        assert scan.labels is not None  # synthetic rooms are labelled
        out[i] = np.bincount(scan.labels, minlength=NUM_CLASSES) / len(scan)
    return out


def main() -> None:
    """Print the share table and generation times."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--points", type=int, default=200_000, help="points per room for the shares")
    ap.add_argument("--seeds", type=int, default=10, help="seeds 0..K-1")
    args = ap.parse_args()
    header()
    seeds = range(args.seeds)
    box, ell = shares("box", seeds, args.points), shares("L", seeds, args.points)
    s3dis = S3DIS_COUNTS / S3DIS_COUNTS.sum()
    both = np.concatenate([box, ell]).mean(axis=0)
    print(f"per-class point share, seeds 0-{args.seeds - 1}, {args.points} points per room")
    head = ("S3DIS", "box", "L", "both")
    print(f"{'class':10s} " + " ".join(f"{h:>7s}" for h in head) + f" {'ratio':>6s} {'rooms':>6s}")
    present = (np.concatenate([box, ell]) > 0).sum(axis=0)
    for c in range(NUM_CLASSES):
        print(
            f"{CLASS_NAMES[c]:10s} {100 * s3dis[c]:6.1f}% {100 * box[:, c].mean():6.1f}% "
            f"{100 * ell[:, c].mean():6.1f}% {100 * both[c]:6.1f}% {both[c] / s3dis[c]:6.2f} "
            f"{present[c]:3d}/{2 * args.seeds}"
        )
    n_classes = (np.concatenate([box, ell]) > 0).sum(axis=1)
    print(f"classes per room: min {n_classes.min()}, mean {n_classes.mean():.1f}")
    print("generation time for 1 000 000 points (best of 2):")
    print(f"  make_room box : {best_time(lambda: make_room(0, points=1_000_000), 2):.2f} s")
    print(
        f"  make_room L   : {best_time(lambda: make_room(0, points=1_000_000, shape='L'), 2):.2f} s"
    )
    print(f"  make_floor    : {best_time(lambda: make_floor(0, points=1_000_000), 2):.2f} s")


if __name__ == "__main__":
    main()
