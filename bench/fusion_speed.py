"""Fusion time per variant on one synthetic room, against the paper's rule in the same process.

The network is a stand-in (ground truth with patchy label noise and probabilities,
jointseg.synth.label_noise); the segments are the real geometry's. Prints seconds per variant
(best of --repeat), seconds per million points and the ratio to `paper`.

    .venv/bin/python bench/fusion_speed.py [--points 1000000] [--repeat 3]
    git show HEAD~1:jointseg/fusion/vote_model.json > /tmp/old_vote.json
    .venv/bin/python bench/fusion_speed.py --baseline-model /tmp/old_vote.json

--baseline-model also times 'learned' with another vote model in the same process, to compare
a refitted model's speed with the one it replaces.
"""

from __future__ import annotations

import argparse
import functools
import logging
from pathlib import Path

import numpy as np
from helpers.measure import best_time
from helpers.report import header

from jointseg.fusion import FusionParams, fuse, learned
from jointseg.fusion.variants import VARIANTS
from jointseg.geometry import segment
from jointseg.synth import make_room
from jointseg.synth.label_noise import corrupt_labels


def use_model(path: Path) -> None:
    """Make the learned vote use the model at ``path`` (the vote reads the shipped model through
    this module function at call time)."""
    model = learned.TreeEnsemble.from_json(path)
    learned.shipped_model = lambda: model  # type: ignore[assignment]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--baseline-model", type=Path, help="another vote model JSON to time")
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.WARNING)
    scan = make_room(0, points=args.points)
    segments = segment(scan, seed=0).segments
    assert scan.labels is not None  # synthetic rooms are labelled
    labels, probs = corrupt_labels(scan.xyz, scan.labels, rng=np.random.default_rng(0))
    print(f"# fusion speed, {len(scan):,} points, {segments.max() + 1} segments\n")
    print("| variant | seconds | s per 1 M points | x paper |")
    print("|---|---|---|---|")
    runs: list[tuple[str, FusionParams, Path | None]] = [
        (name, params, None) for name, params in VARIANTS.items()
    ]
    if args.baseline_model:
        name = f"learned, {args.baseline_model.name}"
        runs.append((name, VARIANTS["learned"], args.baseline_model))
    base = None
    for name, params, model in runs:
        if model is not None:
            use_model(model)
        best = best_time(
            functools.partial(fuse, scan.xyz, segments, labels, probs, params), args.repeat
        )
        base = base or best
        per_m = best / len(scan) * 1e6
        print(f"| {name} | {best:.3f} | {per_m:.3f} | {best / base:.2f} |")


if __name__ == "__main__":
    main()
