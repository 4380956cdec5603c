"""Fit the learned vote (jointseg/fusion/vote_model.json) on real tuning rooms and synthetic rooms.

Training points are those where a segment's soft-majority label differs from the network's and
one of the two is the truth; the target is "the segment's label is the right one". Each room
weighs the same, and inside a room a point weighs by the inverse frequency of its true class
(mIoU counts every class alike). Real tuning rooms are labelled by DGCNN model_6 (it never saw
Area_6) and synthetic calibration rooms (seeds 7000+, never a benchmark's held-out seed) by the
bundled RandLA-Net, so the rule sees a strong network on impure real segments and a weak one on
clean synthetic segments. The judging rooms of bench/fusion_real.py are never read.

    .venv/bin/python bench/fit_vote.py            # writes jointseg/fusion/vote_model.json
    .venv/bin/python bench/fusion_real.py ...     # then judge it
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier

from jointseg.fusion.learned import FEATURES, MODEL_PATH, vote_features
from jointseg.synth import make_floor, make_room

sys.path.insert(0, str(Path(__file__).parent))
import fusion_real as fr  # noqa: E402

M6 = f"dgcnn:{fr.SHARED / 'models' / 'dgcnn_s3dis' / 'model_6.t7'}"
CALIBRATION_SEED = 7000


def calibration_rooms(rooms: int, floors: int, points: int) -> list[fr.Item]:
    """Synthetic rooms and floors with seeds no benchmark holds out."""
    out = []
    for i in range(rooms):
        shape = "L" if i % 2 else "box"
        name = f"room {CALIBRATION_SEED + i} ({shape})"
        scan = make_room(CALIBRATION_SEED + i, points=points, shape=shape)
        out.append(fr.Item(name, scan, fr.content_key(name, points), "calibration"))
    for i in range(floors):
        name = f"floor {CALIBRATION_SEED + 100 + i}"
        scan = make_floor(CALIBRATION_SEED + 100 + i, points=3 * points)
        out.append(fr.Item(name, scan, fr.content_key(name, points), "calibration"))
    return out


def room_samples(item: fr.Item, spec: str, predictors: dict) -> tuple[np.ndarray, ...]:
    """Features, targets and weights of one room's open points."""
    labels, probs = fr.network_output(spec, item, predictors)
    seg = fr.geometry_output("default", item)["segments"].astype(np.int64)
    gt = item.scan.labels
    assert gt is not None
    candidate, open_, x = vote_features(seg, int(seg.max()) + 1, labels, probs)
    truth = gt[open_]
    useful = (truth == candidate[open_]) | (truth == labels[open_])
    freq = np.bincount(gt[gt >= 0], minlength=13) / max(int((gt >= 0).sum()), 1)
    w = 1.0 / (freq[truth[useful]] + 0.02)
    return x[useful], truth[useful] == candidate[open_][useful], w / w.sum()


def export(clf: HistGradientBoostingClassifier) -> dict:
    """The fitted ensemble as plain arrays (see jointseg.fusion.learned.TreeEnsemble)."""
    trees = []
    for (predictor,) in clf._predictors:
        nodes = predictor.nodes
        trees.append(
            {
                "feature": nodes["feature_idx"].tolist(),
                "threshold": nodes["num_threshold"].tolist(),
                "left": nodes["left"].tolist(),
                "right": nodes["right"].tolist(),
                "value": nodes["value"].tolist(),
                "leaf": nodes["is_leaf"].astype(bool).tolist(),
            }
        )
    return {"base": float(np.ravel(clf._baseline_prediction)[0]), "trees": trees}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--judge", type=int, default=10, help="real judging rooms left out")
    parser.add_argument("--synth-rooms", type=int, default=6)
    parser.add_argument("--synth-floors", type=int, default=1)
    parser.add_argument("--synth-points", type=int, default=100_000)
    parser.add_argument("--trees", type=int, default=100)
    parser.add_argument("--depth", type=int, default=3)
    parser.add_argument("--min-leaf", type=int, default=20, help="least samples per leaf")
    parser.add_argument("--l2", type=float, default=0.0, help="L2 regularisation of leaves")
    parser.add_argument("--out", type=Path, default=MODEL_PATH)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)
    real = [i for i in fr.load_items([str(fr.AREA6)], args.judge, (0, 0, 0)) if i.split == "tune"]
    synth = calibration_rooms(args.synth_rooms, args.synth_floors, args.synth_points)
    predictors: dict = {}
    parts = [room_samples(i, M6, predictors) for i in real]
    parts += [room_samples(i, "randlanet", predictors) for i in synth]
    x = np.concatenate([p[0] for p in parts])
    y = np.concatenate([p[1] for p in parts])
    w = np.concatenate([p[2] for p in parts]) * len(parts)
    t = time.perf_counter()
    clf = HistGradientBoostingClassifier(
        max_depth=args.depth,
        max_iter=args.trees,
        min_samples_leaf=args.min_leaf,
        l2_regularization=args.l2,
        random_state=0,
    ).fit(x, y, sample_weight=w)
    body = {
        "features": list(FEATURES),
        **export(clf),
        "card": {
            "what": "P(a segment's soft-majority label is right where the network disagrees)",
            "trained_on": {
                "real": [i.name for i in real],
                "real_network": "DGCNN model_6 (dgcnn.pytorch, Area 6 never seen)",
                "synthetic": [i.name for i in synth],
                "synthetic_network": "bundled RandLA-Net",
                "synthetic_points": args.synth_points,
                "geometry": "GeometryParams() defaults",
            },
            "samples": int(len(y)),
            "trees": args.trees,
            "max_depth": args.depth,
            "min_samples_leaf": args.min_leaf,
            "l2_regularization": args.l2,
            "command": "bench/fit_vote.py " + " ".join(sys.argv[1:]),
            "date": time.strftime("%F"),
            "data_terms": "real rooms are derived from S3DIS (Stanford; research use, cite "
            "Armeni et al. 2016); the model stores only split thresholds and leaf values",
        },
    }
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(json.dumps(body, separators=(",", ":")))
    tmp.replace(args.out)
    print(
        f"{len(y)} samples from {len(real)} real and {len(synth)} synthetic rooms, "
        f"fitted in {time.perf_counter() - t:.1f} s -> {args.out} ({args.out.stat().st_size} bytes)"
    )


if __name__ == "__main__":
    main()
