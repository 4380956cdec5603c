"""Whole-process time of `jointseg segment` with the frame stage against the code before it,
in the same command (issue 31's bar: a 1 M-point room no slower than 1.1x; issue 41's: the
frame stage itself, the network judging included, at most 1 s).

The baseline is a git worktree of ``--baseline`` (default: the last commit before the frame
stage) run with the same Python; the runs alternate (old, new, old, new, ...) so that load on
the machine hits both alike. Prints per run and the medians, and the frame stage's own seconds
from the new report.

    .venv/bin/python bench/frame_speed.py [--points 1000000] [--seed 1501] [--repeats 3]
        [--baseline 0ae0b2e]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from helpers.report import header

ROOT = Path(__file__).resolve().parents[1]


def timed_segment(code: Path, scan: Path, out: Path) -> tuple[float, dict]:
    """Seconds of one whole `python -m jointseg segment` process running ``code``'s package."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    report = out.with_suffix(".json")
    t = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "jointseg", "segment", str(scan), "-o", str(out),
         "--report", str(report)],
        check=True, env=env, cwd=code, capture_output=True,
    )  # fmt: skip
    return time.perf_counter() - t, json.loads(report.read_text())


def turn_y_up(path: Path) -> None:
    """Rewrite the scan at ``path`` turned y up ((x, y, z) -> (x, z, -y)), as glTF and many
    exports deliver."""
    from dataclasses import replace

    from jointseg.io import read_scan, write_scan

    scan = read_scan(path)
    xyz = scan.xyz[:, [0, 2, 1]] * [1.0, 1.0, -1.0]
    write_scan(replace(scan, xyz=xyz), path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=1501)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline", default="0ae0b2e")
    ap.add_argument(
        "--deliver", default="+z", choices=("+z", "+y"),
        help="+y: the room turned y up first (a plain y-up export: the network judges)",
    )  # fmt: skip
    args = ap.parse_args()
    header()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        old = work / "old"
        subprocess.run(
            ["git", "worktree", "add", "--detach", str(old), args.baseline],
            check=True, cwd=ROOT, capture_output=True,
        )  # fmt: skip
        try:
            scan = work / "room.ply"
            subprocess.run(
                [sys.executable, "-m", "jointseg", "synth", "--seed", str(args.seed),
                 "--points", str(args.points), "-o", str(scan)],
                check=True, cwd=ROOT, capture_output=True,
            )  # fmt: skip
            if args.deliver == "+y":
                turn_y_up(scan)
            rows: dict[str, list[float]] = {"before": [], "frame stage": []}
            frame_s: list[float] = []
            old_frame_s: list[float] = []
            labels_same = []
            for i in range(args.repeats):
                a, old_report = timed_segment(old, scan, work / f"old{i}.ply")
                b, new_report = timed_segment(ROOT, scan, work / f"new{i}.ply")
                rows["before"].append(a)
                rows["frame stage"].append(b)
                frame_s.append(new_report["timings_s"].get("frame", float("nan")))
                old_frame_s.append(old_report["timings_s"].get("frame", float("nan")))
                labels_same.append(
                    old_report["metrics"]["fused"]["miou"] == new_report["metrics"]["fused"]["miou"]
                )
                print(f"run {i + 1}: before {a:.2f} s, with the frame stage {b:.2f} s", flush=True)
        finally:
            subprocess.run(
                ["git", "worktree", "remove", "--force", str(old)], cwd=ROOT, capture_output=True
            )
    before, after = (statistics.median(v) for v in rows.values())
    print(f"\n{args.points:,}-point synthetic room (seed {args.seed}), whole process, "
          f"median of {args.repeats}")  # fmt: skip
    print("| code | seconds | ratio |")
    print("|---|---|---|")
    print(f"| before ({args.baseline}) | {before:.2f} | 1.00 |")
    print(f"| with the frame stage | {after:.2f} | {after / before:.3f} |")
    same = f"{sum(labels_same)} of {len(labels_same)}"
    print(f"frame stage itself: median {statistics.median(frame_s):.2f} s "
          f"(before: {statistics.median(old_frame_s):.2f} s); "
          f"same fused mIoU as before in {same} runs")  # fmt: skip


if __name__ == "__main__":
    main()
