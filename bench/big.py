"""Big scans through `jointseg segment`: peak memory and time against the number of points,
whole scan in memory (untiled) against tile by tile (issue 16).

Each size is a synthetic floor (`jointseg synth --floor`, rooms growing with the points) written
as LAZ, then segmented by the command a user types, in a fresh process, once per mode:

- ``untiled``: ``--tile-points`` above the size, so the whole scan, its probabilities and its
  segments live in memory at once;
- ``tiled``: the default tile size (``--tile-points`` to change it): spilled to disk, network and
  geometry tile by tile, segments joined across borders, output streamed.
- ``untiled+ifc``, ``tiled+ifc``: the same, also writing ``--objects`` and ``--ifc`` (issue 33's
  bound: the IFC export of a 20 M-point floor within the memory of the run without it).

The peak resident memory of that process (getrusage of a wrapper's only child) and its wall
time are printed with the report's stage times. Time per point is compared with the untiled run
at ``--baseline`` points measured in the same command (the issue's bar: at most 1.2x). Where
both modes ran on one size, the share of points whose fused (and network) label is the same in
both outputs is printed too.

    .venv/bin/python bench/big.py [--sizes 1000000,4000000,20000000] [--modes untiled,tiled]
        [--tile-points N] [--baseline 4000000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from helpers.inputs import cached_floor
from helpers.measure import PEAK_WRAPPER
from helpers.report import header


def segment(scan: Path, out: Path, tile_points: int, ifc: bool = False) -> dict[str, Any]:
    """`jointseg segment` on ``scan`` in a child process: wall time, peak RSS, stage times
    (seconds), and for a failed run why; with ``ifc``, objects.json and an IFC model written
    too (the ``+ifc`` modes)."""
    report = out.with_suffix(".json")
    cmd = [sys.executable, "-c", PEAK_WRAPPER, sys.executable, "-m", "jointseg", "segment"]
    cmd += [str(scan), "-o", str(out), "--report", str(report)]
    cmd += ["--tile-points", str(tile_points)]
    if ifc:
        cmd += ["--objects", str(out.with_suffix(".objects.json"))]
        cmd += ["--ifc", str(out.with_suffix(".ifc"))]
    t = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    peak_kib = int(done.stderr.strip().splitlines()[-1])
    if done.returncode != 0:
        tail = done.stderr.strip().splitlines()[-3:-1]
        return {"wall": wall, "failed": 1.0, "peak_gb": peak_kib / 1024**2, "why": str(tail)}
    body = json.loads(report.read_text())
    tiles = body.get("tiles") or {"count": 1}
    return {
        "wall": wall,
        "peak_gb": peak_kib / 1024**2,
        **body["timings_s"],
        "tile_count": tiles["count"],
    }


def agreement(a: Path, b: Path) -> tuple[float, float]:
    """Share of points with the same fused and the same network label in two outputs."""
    from jointseg.io import read_scan

    x, y = read_scan(a, max_points=10**9), read_scan(b, max_points=10**9)
    fused = float(np.mean(x.fields["fused_label"] == y.fields["fused_label"]))
    network = float(np.mean(x.fields["network_label"] == y.fields["network_label"]))
    return fused, network


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000000,4000000")
    parser.add_argument("--modes", default="untiled,tiled", help="also untiled+ifc, tiled+ifc")
    parser.add_argument("--tile-points", type=int, default=4_000_000)
    parser.add_argument("--baseline", type=int, default=4_000_000)
    parser.add_argument("--agree-max", type=int, default=4_000_000, help="compare labels up to")
    parser.add_argument("--keep", type=Path, help="keep the generated floors in this folder")
    args = parser.parse_args()
    header()
    sizes = sorted(int(s) for s in args.sizes.split(",") if s)
    modes = [m for m in args.modes.split(",") if m]
    today = time.strftime("%F")
    print(f"# big scans, {today}, {os.cpu_count()} CPUs, tile size {args.tile_points:,}\n")
    print(
        "| points | mode | tiles | whole process s | s per M points | vs untiled at baseline "
        "| peak GB | read/prepare | network+geometry | fusion | write | same fused / network |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    baseline: float | None = None
    with tempfile.TemporaryDirectory(prefix="jointseg-big-") as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for points in sizes:
            scan = cached_floor(points, folder)
            outputs: dict[str, Path] = {}
            for mode in modes:
                out = Path(tmp) / f"out_{points}_{mode}.laz"
                tile_points = 10**9 if mode.startswith("untiled") else args.tile_points
                row = segment(scan, out, tile_points, ifc=mode.endswith("+ifc"))
                if row.get("failed"):
                    print(
                        f"| {points:,} | {mode} | | failed after {row['wall']:.0f} s "
                        f"({row['why']}) | | | {row['peak_gb']:.2f} | | | | | |",
                        flush=True,
                    )
                    continue
                outputs[mode] = out
                per_m = row["wall"] / points * 1e6
                if mode == "untiled" and points == args.baseline:
                    baseline = per_m
                ratio = f"{per_m / baseline:.2f}x" if baseline else "-"
                read = row.get("prepare", row.get("read", float("nan")))
                # network and geometry overlap in time: the tiles' total, or the longer one
                side = max(row.get("network", 0.0), row.get("geometry", 0.0))
                work = row.get("tiles", side)
                fusion, write = row.get("fusion", float("nan")), row.get("write", float("nan"))
                same = "-"
                if {"untiled", "tiled"} <= outputs.keys() and points <= args.agree_max:
                    fused, network = agreement(outputs["untiled"], outputs["tiled"])
                    same = f"{fused:.4f} / {network:.4f}"
                print(
                    f"| {points:,} | {mode} | {int(row['tile_count'])} | {row['wall']:.1f} "
                    f"| {per_m:.2f} | {ratio} | {row['peak_gb']:.2f} | {read:.1f} | {work:.1f} "
                    f"| {fusion:.1f} | {write:.1f} | {same} |",
                    flush=True,
                )
            for out in outputs.values():
                for extra in (out, out.with_suffix(".ifc"), out.with_suffix(".objects.json")):
                    extra.unlink(missing_ok=True)


if __name__ == "__main__":
    main()
