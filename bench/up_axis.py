"""Up-axis decision of the frame stage: fit its two logistic steps on tuning scans, judge them
on the others, each scan delivered with every signed axis up and a random tilt and yaw.

    python bench/up_axis.py            # judge the weights in jointseg/frame/up_model.json
    python bench/up_axis.py --fit      # fit them on the tuning scans first and write them

Judged with the delivery prior of jointseg/frame/gravity.py (DELIVERY) and without it
(--no-prior), since the uniform mix of directions here is not how scans arrive.

Prints per split: axis right, sign right, both right (of scans x 6 directions x --turns).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from jointseg.frame import gravity
from jointseg.frame.decide import rotation_about
from jointseg.io import read_scan
from jointseg.synth import make_room

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
JUDGING = ("area6_office_4", "scene0002", "scene0005", "scene0007")


def to_axis(target: str) -> np.ndarray:
    """A proper rotation taking +z to the signed axis ``target``."""
    want = gravity.AXES[target]
    if abs(want[2]) > 0.5:
        return np.eye(3) if want[2] > 0 else rotation_about(np.array([1.0, 0, 0]), 180)
    return rotation_about(np.cross([0.0, 0.0, 1.0], want), 90)


def scans() -> list[tuple[str, np.ndarray, bool]]:
    """(name, xyz in metres z up, judging?) for every real scan and four synthetic rooms."""
    out = []
    for folder in ("s3dis_area6", "scannet"):
        for path in sorted((SHARED / folder).glob("*.ply")):
            judge = any(path.stem.startswith(j) for j in JUDGING)
            out.append((path.stem, read_scan(path).xyz, judge))
    for seed in range(9201, 9213):
        room = make_room(seed, points=200_000, shape="L" if seed % 3 == 0 else "box")
        out.append((f"synth{seed}", room.xyz, seed >= 9210))
    return out


def rows(turns: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    out = []
    for name, xyz, judge in scans():
        for target in gravity.AXES:
            for _ in range(turns):
                tilt = rotation_about(np.array([*rng.normal(size=2), 0.0]), rng.uniform(0, 20))
                yaw = rotation_about(np.array([0.0, 0.0, 1.0]), rng.uniform(0, 360))
                r = to_axis(target) @ tilt @ yaw
                moved = xyz @ r.T
                sample = gravity.frame_sample(moved, rng)
                true_axis = "xyz".index(target[1])
                d = sample.directions[true_axis]
                d = d if d[true_axis] >= 0 else -d
                out.append(
                    {
                        "name": name,
                        "judge": judge,
                        "target": target,
                        "axis_f": gravity.axis_features(sample),
                        "true_axis": true_axis,
                        "sign_f": gravity.sign_features(sample, d, 1.0),
                        "plus": target[0] == "+",
                        "sample": sample,
                    }
                )
    return out


def fit(train: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    from sklearn.linear_model import LogisticRegression

    # axis: each scan's three rows against each other -> pairwise differences, true minus other
    xa, ya = [], []
    for r in train:
        f = r["axis_f"]
        for j in range(3):
            if j != r["true_axis"]:
                xa += [f[r["true_axis"]] - f[j], f[j] - f[r["true_axis"]]]
                ya += [1, 0]
    axis_model = LogisticRegression(fit_intercept=False, C=3.0, max_iter=5000)
    axis_model.fit(np.array(xa), ya)
    xs = np.array([r["sign_f"] * (1 if r["plus"] else -1) for r in train])
    xs = np.concatenate([xs, -xs])
    ys = np.r_[np.ones(len(train)), np.zeros(len(train))]
    sign_model = LogisticRegression(fit_intercept=False, C=3.0, max_iter=5000).fit(xs, ys)
    return axis_model.coef_[0], sign_model.coef_[0]


def judge(items: list[dict]) -> tuple[int, int, int, int]:
    axis_ok = sign_ok = both = 0
    for r in items:
        a, p = gravity.vertical_axis(r["sample"])
        est = gravity.estimate_up(r["sample"], a, p, 1.0)
        axis_ok += a == r["true_axis"]
        sign_ok += (
            gravity.up_sign(r["sample"], r["true_axis"], 1.0) >= 0.5
            if r["plus"]
            else (gravity.up_sign(r["sample"], r["true_axis"], 1.0) < 0.5)
        )
        both += est.axis == r["target"]
    return axis_ok, sign_ok, both, len(items)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--fit", action="store_true", help="fit the weights on the tuning scans")
    ap.add_argument("--turns", type=int, default=2, help="random tilts per scan and direction")
    ap.add_argument("--no-prior", action="store_true", help="judge without the delivery prior")
    ap.add_argument(
        "--prior-scale", type=float, default=gravity.PRIOR_SCALE, help="judge with the prior x this"
    )
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t = time.perf_counter()
    items = rows(args.turns, args.seed)
    built = time.perf_counter() - t
    if args.fit:
        aw, sw = fit([r for r in items if not r["judge"]])
        gravity.AXIS_WEIGHTS = aw
        gravity.SIGN_WEIGHTS = sw
        gravity.MODEL_FILE.write_text(
            json.dumps(
                {
                    "axis_weights": np.round(aw, 5).tolist(),
                    "sign_weights": np.round(sw, 5).tolist(),
                    "fitted_on": sorted({r["name"] for r in items if not r["judge"]}),
                    "command": "python bench/up_axis.py --fit",
                },
                indent=1,
            )
            + "\n"
        )
        print(f"wrote {gravity.MODEL_FILE}")
    scale = 0.0 if args.no_prior else args.prior_scale
    gravity.AXIS_PRIOR[:] = gravity.AXIS_PRIOR * scale / gravity.PRIOR_SCALE
    gravity.SIGN_PRIOR[:] = gravity.SIGN_PRIOR * scale / gravity.PRIOR_SCALE
    targets = list(gravity.AXES)
    print(f"({built:.0f} s to build the cases)")
    print(
        "| split | cases | axis right | sign right | both right | "
        + " | ".join(targets)
        + " | weighted by delivery |"
    )
    print("|---|---|---|---|---|" + "---|" * (len(targets) + 1))
    for split, judge_flag in (("tuning", False), ("judging", True)):
        part = [r for r in items if r["judge"] == judge_flag]
        a, s, b, n = judge(part)
        per = {t: judge([r for r in part if r["target"] == t]) for t in targets}
        shares = {t: per[t][2] / max(per[t][3], 1) for t in targets}
        weighted = sum(gravity.DELIVERY[t] * shares[t] for t in targets)
        cells = " | ".join(f"{shares[t]:.2f}" for t in targets)
        print(f"| {split} | {n} | {a} | {s} | {b} | {cells} | {weighted:.3f} |")
    wrong = [
        (r["name"], r["target"])
        for r in items
        if gravity.estimate_up(r["sample"], *gravity.vertical_axis(r["sample"]), 1.0).axis
        != r["target"]
    ]
    print("wrong:", wrong[:40])


if __name__ == "__main__":
    main()
