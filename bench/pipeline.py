"""End-to-end speed and memory of the pipeline on CPU: one synthetic room, then how the total
grows with the number of points.

Every measurement runs in a fresh subprocess that reads a pre-generated scan and runs
`jointseg.pipeline.run`, so its peak resident memory (getrusage) is the pipeline's own, not
the room generator's or another size's. Prints per-stage times (network and geometry overlap:
they run concurrently unless --sequential), the total, the peak RSS, and a table from 250 k to
4 M points. Target (issue 5): 1 M points in <= 20 s and <= 4 GB on 2 cores.

    .venv/bin/python bench/pipeline.py [--weights PATH | --random-weights] [--points 1000000]
        [--sizes 250000,500000,1000000,2000000,4000000] [--sequential]

--random-weights times a randomly initialised network of the same shape (the time does not
depend on the weights' values; the labels are meaningless).
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

from helpers.measure import peak_rss_mb
from helpers.report import header

STAGES = ("network", "geometry", "fusion", "metrics")


def measure_one(scan_path: Path, weights: str, sequential: bool) -> dict[str, Any]:
    """Child process: read the scan, run the pipeline once, return timings and peak memory."""
    from jointseg.io import read_scan
    from jointseg.pipeline import PipelineConfig, load_predictor, run

    config = PipelineConfig.model_validate(
        {"network": {"weights": weights, "device": "cpu"}, "concurrent": not sequential}
    )
    t = time.perf_counter()
    predictor = load_predictor(config.network)
    load_s = time.perf_counter() - t
    scan = read_scan(scan_path)
    rss_before = peak_rss_mb()
    result = run(scan, config, predictor=predictor)
    import torch

    return {
        "points": len(scan),
        "load_network": load_s,
        **{k: v for k, v in result.timings.items() if k != "load_network"},
        "segments": result.geometry.n_segments,
        "crops": result.network.crops,
        "peak_rss_mb": peak_rss_mb(),
        "rss_before_run_mb": rss_before,
        "torch_threads": torch.get_num_threads(),
    }


def run_child(scan_path: Path, weights: str, sequential: bool) -> dict[str, Any]:
    cmd = [sys.executable, __file__, "--single", str(scan_path), "--weights", weights]
    if sequential:
        cmd.append("--sequential")
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def make_scan(points: int, folder: Path, suffix: str = ".npz") -> Path:
    from jointseg.io import write_scan
    from jointseg.synth import make_room

    path = folder / f"room_{points}{suffix}"
    if not path.exists():
        write_scan(make_room(0, points=points), path)
    return path


def one_shot(scan_path: Path, weights: str, folder: Path) -> dict[str, float]:
    """`jointseg segment SCAN -o OUT.ply --report R` as a user runs it, in a fresh process:
    its wall-clock time, and the report's stage times (the rest is start-up and imports)."""
    report = folder / "one_shot.json"
    cmd = [
        sys.executable,
        "-m",
        "jointseg",
        "segment",
        str(scan_path),
        "-o",
        str(folder / "one_shot.ply"),
        "--report",
        str(report),
        "--weights",
        weights,
    ]
    t = time.perf_counter()
    subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t
    stages = json.loads(report.read_text())["timings_s"]
    return {"whole process": wall, **stages}


def random_weights(folder: Path) -> str:
    import torch

    from jointseg.network.randlanet.checkpoint import save_checkpoint
    from jointseg.network.randlanet.model import RandLANet, RandLANetConfig

    torch.manual_seed(0)
    path = folder / "random.pt"
    save_checkpoint(path, RandLANet(RandLANetConfig()), {"data": "random (timing only)"})
    return str(path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", default=None, help="default: the bundled weights")
    parser.add_argument("--random-weights", action="store_true")
    parser.add_argument("--points", type=int, default=1_000_000)
    parser.add_argument("--sizes", default="250000,500000,1000000,2000000,4000000")
    parser.add_argument("--sequential", action="store_true", help="network, then geometry")
    parser.add_argument("--single", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.single is not None:  # a child run: one JSON line the parent reads
        print(json.dumps(measure_one(args.single, args.weights, args.sequential)))
        return
    header()

    from jointseg.network.registry import REGISTRY

    with tempfile.TemporaryDirectory(prefix="jointseg-bench-") as tmp:
        folder = Path(tmp)
        if args.random_weights:
            weights = random_weights(folder)
        else:
            weights = args.weights or str(REGISTRY["randlanet"].bundled)
        print(
            f"# pipeline benchmark, {time.strftime('%F')}, {os.cpu_count()} CPUs, weights {weights}"
        )
        print(f"concurrent network and geometry: {not args.sequential}\n")

        main_row = run_child(make_scan(args.points, folder), weights, args.sequential)
        print(f"## {args.points:,} points (torch threads {main_row['torch_threads']})\n")
        print("| stage | seconds |")
        print("|---|---|")
        for stage in ("load_network", *STAGES):
            print(f"| {stage} | {main_row[stage]:.2f} |")
        print(f"| sum of stages | {sum(main_row[s] for s in STAGES):.2f} |")
        print(f"| **total (pipeline.run)** | **{main_row['total']:.2f}** |")
        print(
            f"\npeak RSS {main_row['peak_rss_mb']:,.0f} MB "
            f"(before the run, with torch, the network and the scan: "
            f"{main_row['rss_before_run_mb']:,.0f} MB);"
            f" {main_row['segments']:,} segments, {main_row['crops']} network crops\n"
        )

        shot = one_shot(make_scan(args.points, folder, ".ply"), weights, folder)
        print("## one-shot `jointseg segment` of the same room as a .ply, whole process (s)\n")
        print("| " + " | ".join(shot) + " | start-up, imports and the rest |")
        print("|---" * (len(shot) + 1) + "|")
        rest = shot["whole process"] - shot["total"]  # the report's total includes read/write
        print("| " + " | ".join(f"{v:.2f}" for v in shot.values()) + f" | {rest:.2f} |\n")

        sizes = [int(s) for s in args.sizes.split(",") if s]
        print("## scaling\n")
        print("| points | network s | geometry s | fusion s | total s | s per M points | peak MB |")
        print("|---|---|---|---|---|---|---|")
        for points in sizes:
            row = main_row if points == args.points else None
            row = row or run_child(make_scan(points, folder), weights, args.sequential)
            print(
                f"| {points:,} | {row['network']:.2f} | {row['geometry']:.2f} | "
                f"{row['fusion']:.3f} | {row['total']:.2f} | {row['total'] / points * 1e6:.2f} | "
                f"{row['peak_rss_mb']:,.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
