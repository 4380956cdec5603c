"""Big scans through `jointseg segment`: peak memory and time against the number of points.

Each size is a synthetic floor (`jointseg synth --floor`, rooms growing with the points) written
as LAZ, then segmented by the command a user types, in a fresh process; the peak resident memory
of that process (getrusage of the child) and its wall-clock time are printed with the report's
stage times. This is the baseline issue 16 measures the tiled pipeline against: today the whole
scan, its probabilities and its segments live in memory at once.

    .venv/bin/python bench/big.py [--sizes 1000000,4000000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Points per synthetic room of the floor (a 20 M-point floor has about 28 rooms).
POINTS_PER_ROOM = 700_000


def make_floor(points: int, folder: Path) -> Path:
    """A cached synthetic floor of ``points`` points as LAZ."""
    path = folder / f"floor_{points}.laz"
    if not path.exists():
        rooms = max(2, round(points / POINTS_PER_ROOM))
        cmd = [sys.executable, "-m", "jointseg", "synth", "-o", str(path), "--floor", str(rooms)]
        cmd += ["--points", str(points), "--seed", "1"]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
    return path


def segment(scan: Path, folder: Path) -> dict[str, float]:
    """`jointseg segment` on ``scan`` in a child process: wall time, peak RSS, stage times."""
    report = folder / "report.json"
    cmd = [sys.executable, "-m", "jointseg", "segment", str(scan), "-o"]
    cmd += [str(folder / "out.laz"), "--report", str(report)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if done.returncode != 0:
        return {"wall": wall, "failed": 1.0, "peak_gb": float("nan")}
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    stages = json.loads(report.read_text())["timings_s"]
    # ru_maxrss of children is the largest child so far; sizes run in increasing order
    return {"wall": wall, "peak_gb": max(peak, before) / 1024**2, **stages}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000000,4000000")
    parser.add_argument("--keep", type=Path, help="keep the generated floors in this folder")
    args = parser.parse_args()
    sizes = sorted(int(s) for s in args.sizes.split(",") if s)
    print(f"# big scans, {time.strftime('%F')}, {os.cpu_count()} CPUs, untiled pipeline\n")
    print(
        "| points | whole process s | s per M points | peak GB | read | network | geometry "
        "| fusion | write |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory(prefix="jointseg-big-") as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for points in sizes:
            row = segment(make_floor(points, folder), Path(tmp))
            if row.get("failed"):
                print(f"| {points:,} | failed after {row['wall']:.0f} s | | | | | | | |")
                continue
            cells = " | ".join(
                f"{row.get(k, float('nan')):.1f}"
                for k in ("read", "network", "geometry", "fusion", "write")
            )
            print(
                f"| {points:,} | {row['wall']:.1f} | {row['wall'] / points * 1e6:.2f} | "
                f"{row['peak_gb']:.2f} | {cells} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
