"""GPU inference benchmark (issue 25): whole-scan RandLA-Net and DGCNN through the library, on a
GPU and on the CPU in the same run.

For each backend, `jointseg.network.load(...).predict(scan)` best of `--repeats` on `--device`
(default: cuda when present) and best of `--cpu-repeats` on the CPU with all its threads
(`--no-cpu` skips those), on about `--points` points: real S3DIS Area_6 rooms laid side by side in
x (../shared/data/s3dis_area6; a synthetic floor when absent). Prints seconds, M points/s, the
split of the time (the result's `timings`), peak GPU memory and the GPU's utilisation sampled from
`nvidia-smi`. `--segment-floor N` also times `jointseg segment --device ...` on a synthetic N-point
floor and prints the network stage's and the geometry's share of it. A table, no assertions; it
runs on a CPU-only machine too (the device rows then say cpu).

    .venv/bin/python bench/gpu.py [--points 1030000] [--repeats 3] [--batch-size 32]
    .venv/bin/python bench/gpu.py --points 200000 --repeats 1 --segment-floor 20000000
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from helpers.gpu_usage import GpuUsage
from helpers.inputs import AREA6, CACHE, MODELS, cached_floor
from helpers.report import header
from helpers.side_by_side import rooms_side_by_side

from jointseg.network import load
from jointseg.network.base import synchronize
from jointseg.scan import Scan

#: RandLA-Net trained for the GPU path, when it is there (else the bundled weights).
RANDLANET_GPU = MODELS / "randlanet_area6_gpu" / "randlanet_area6_gpu.pt"
#: DGCNN's S3DIS weights that never saw Area_6.
DGCNN_M6 = MODELS / "dgcnn_s3dis" / "model_6.t7"
ISSUE_POINTS = 1_030_000


@dataclass
class Row:
    """One backend on one device: the best run's seconds and split, memory, utilisation."""

    backend: str
    device: str
    batch: int | str = "-"
    points: int = 0
    seconds: float | None = None
    timings: dict[str, float] = field(default_factory=dict)
    peak_gb: float | None = None
    util: tuple[float | None, float | None] = (None, None)
    note: str = ""

    def line(self) -> str:
        if self.seconds is None:
            return f"| {self.backend} | {self.device} | - | - | - | - | - | - | {self.note} |"
        split = ", ".join(f"{k} {v:.2f}" for k, v in self.timings.items())
        peak = "-" if self.peak_gb is None else f"{self.peak_gb:.2f} GB"
        mean, top = self.util
        util = "-" if mean is None else f"{mean:.0f} % (peak {top:.0f} %)"
        rate = self.points / self.seconds / 1e6
        return (
            f"| {self.backend} | {self.device} | {self.batch} | {self.points:,} | "
            f"{self.seconds:.2f} | {rate:.3g} | {split} | {peak} | {util} | {self.note} |"
        )


def measure(
    backend: str, weights: Path | None, scan: Scan, device: str, batch: int | None, repeats: int
) -> Row:
    """Best of ``repeats`` predicts of ``scan``; the first run's CUDA start-up is in it too, so
    ``repeats`` 1 on a GPU overstates the time."""
    predictor = load(backend, weights, device=device, batch_size=batch)
    dev = torch.device(getattr(predictor, "device", device))
    cuda = dev.type == "cuda"
    if cuda:
        torch.cuda.reset_peak_memory_stats(dev)
    best, timings = float("inf"), {}
    with GpuUsage() if cuda else contextlib.nullcontext() as usage:
        for _ in range(repeats):
            synchronize(dev)
            t = time.perf_counter()
            result = predictor.predict(scan)
            synchronize(dev)
            seconds = time.perf_counter() - t
            if seconds < best:
                best, timings = seconds, dict(result.timings)
    row = Row(backend, str(dev), getattr(predictor, "batch_size", "-"), len(scan), best, timings)
    if cuda:
        row.peak_gb = torch.cuda.max_memory_allocated(dev) / 2**30
        assert usage is not None
        row.util = (usage.mean, usage.peak)
    return row


def backends(args: argparse.Namespace) -> list[tuple[str, Path | None, str]]:
    """(backend, weights, why it is skipped or "") for each backend asked for."""
    out: list[tuple[str, Path | None, str]] = []
    if "randlanet" in args.backends:
        weights = args.randlanet_weights or (RANDLANET_GPU if RANDLANET_GPU.is_file() else None)
        out.append(("randlanet", weights, ""))
    if "dgcnn" in args.backends:
        dgcnn = args.dgcnn_weights or DGCNN_M6
        out.append(("dgcnn", dgcnn, "" if dgcnn.is_file() else f"no weights at {dgcnn}"))
    return out


def input_scan(points: int) -> tuple[Scan, str]:
    """About ``points`` real points (rooms side by side), else a synthetic floor of as many."""
    scan = rooms_side_by_side(points)
    if scan is not None:
        return scan, f"S3DIS Area_6 rooms side by side ({AREA6})"
    from jointseg.synth import make_floor

    rooms = min(32, max(2, round(points / 250_000)))
    return make_floor(1, rooms=rooms, points=points), f"synthetic floor ({rooms} rooms, seed 1)"


def run_rows(args: argparse.Namespace, scan: Scan) -> list[Row]:
    """The device rows, then the CPU rows of the same backends (all threads)."""
    rows: list[Row] = []
    todo = backends(args)
    devices = [args.device]
    if not args.no_cpu and torch.device(args.device).type != "cpu":
        devices.append("cpu")
    for device in devices:
        on_cpu = device == "cpu"
        repeats = args.cpu_repeats if on_cpu and device != args.device else args.repeats
        batch = None if on_cpu and device != args.device else args.batch_size
        for backend, weights, skipped in todo:
            if skipped:
                rows.append(Row(backend, device, note=f"skipped: {skipped}"))
                continue
            row = measure(backend, weights, scan, device, batch, repeats)
            row.note = f"best of {repeats}" + (f", {args.threads} threads" if on_cpu else "")
            rows.append(row)
            print(row.line(), flush=True)
    return rows


def segment_floor(points: int, device: str, weights: Path | None) -> None:
    """`jointseg segment --device` on a synthetic floor: the network stage's and the geometry's
    seconds and their share of the whole run (they run side by side, so shares may add past 1)."""
    CACHE.mkdir(exist_ok=True)
    source = cached_floor(points, CACHE)
    with tempfile.TemporaryDirectory(dir=CACHE) as tmp:
        out, report = Path(tmp) / "out.ply", Path(tmp) / "report.json"
        cmd = [sys.executable, "-m", "jointseg", "segment", str(source), "-o", str(out)]
        cmd += ["--report", str(report), "--device", device]
        cmd += [] if weights is None else ["--weights", str(weights)]
        t = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, text=True)
        wall = time.perf_counter() - t
        body = json.loads(report.read_text())
    timings = body["timings_s"]
    tiles = body.get("steps_s", {}).get("tiles")
    if tiles is not None:  # a tiled run: the stages are per tile
        network = sum(t.get("network", 0.0) for t in tiles)
        geometry = sum(t.get("geometry", 0.0) for t in tiles)
    else:
        network, geometry = timings["network"], timings["geometry"]
    total = timings["total"]
    where = f"in {len(tiles)} tiles" if tiles is not None else "untiled"
    print(f"\n## `jointseg segment --device {device}` on a synthetic floor of {points:,} points")
    print(f"({where}; {wall:.1f} s wall with start-up, report total {total:.1f} s)\n")
    print("| stage | seconds | share of total |")
    print("|---|---|---|")
    for name, seconds in (("network", network), ("geometry", geometry)):
        print(f"| {name} | {seconds:.1f} | {seconds / total:.0%} |")
    rest = {k: round(v, 1) for k, v in timings.items() if k not in ("network", "geometry")}
    print(f"\nother timings (s): {rest}")


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=ISSUE_POINTS)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--cpu-repeats", type=int, default=1)
    parser.add_argument("--no-cpu", action="store_true", help="skip the CPU rows")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--batch-size", type=int, default=None, help="default: the backend's")
    parser.add_argument("--randlanet-weights", type=Path, default=None)
    parser.add_argument("--dgcnn-weights", type=Path, default=None)
    parser.add_argument("--backends", default="randlanet,dgcnn", help="comma-separated")
    parser.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)))
    parser.add_argument("--segment-floor", type=int, default=0, metavar="N")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    header()
    args.backends = set(args.backends.split(","))
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(args.threads)  # the CPU rows use every thread; so does the GPU's prep
    scan, what = input_scan(args.points)
    gpu = torch.cuda.get_device_name() if torch.cuda.is_available() else "no GPU"
    print(f"# whole-scan inference, {len(scan):,} points: {what}")
    print(
        f"torch {torch.__version__}, {gpu}, {os.cpu_count()} CPU cores "
        f"({args.threads} torch threads on the CPU), {time.strftime('%F %H:%M')}\n"
    )
    print(
        "| backend | device | batch | points | seconds | M points/s | split (s) "
        "| peak GPU memory | GPU utilisation | note |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|", flush=True)
    run_rows(args, scan)
    if args.segment_floor:
        weights = args.randlanet_weights or (RANDLANET_GPU if RANDLANET_GPU.is_file() else None)
        segment_floor(args.segment_floor, args.device, weights)


if __name__ == "__main__":
    main()
