"""How fast `jointseg segment` is on two cores, stage by stage, against an older commit (issue 64).

Two parts, both paired against ``--ref`` (checked out into a temporary git worktree) in the same
command, runs interleaved A B A B so a slow spell of the machine hits both:

- **Whole process**: ``jointseg segment ROOM -o OUT --quality Q --report R`` as a user types it,
  each in a fresh process: wall seconds, CPU seconds (user + system of the child), peak
  resident memory; the median of ``--repeats``, the ratio to the old code's, and the report's
  per-stage wall seconds (network and geometry overlap: they run side by side).
- **Stage CPU**: the same pipeline in one process with the stages one after the other
  (``concurrent: false``), each stage's wall and CPU seconds (``time.process_time``, every thread
  of the process), so the cost of each stage is seen without the overlap.

The room is ``jointseg synth --seed 0 --points 1000000`` (``--points`` to change). Every run
uses its own ``JOINTSEG_CACHE`` folder, warmed by one untimed run per tree (the OpenVINO
export and the unpacked weights are made once per machine, not per run).

    .venv/bin/python bench/speed.py [--ref 11aad11] [--presets standard,fast] [--repeats 3]
        [--points 1000000] [--part all|process|stages]

A 20 M-point floor (growth with the points, peak memory): ``bench/big.py --sizes
1000000,20000000 --modes tiled --baseline 1000000``.
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

from helpers.measure import PEAK_WRAPPER
from helpers.report import header

ROOT = Path(__file__).resolve().parents[1]

#: Measures each stage of a sequential run in the child: (module, attribute, stage). A name
#: the tree lacks is skipped, so older commits are measured by the same script.
STAGE_CHILD = r"""
import json, sys, time
from pathlib import Path
sys.argv[0] = "stage-cpu"
room, quality = Path(sys.argv[1]), sys.argv[2]
import jointseg.pipeline.stages as stages
import jointseg.pipeline.side_by_side as sbs
import jointseg.io as jio
from jointseg.pipeline.config import PipelineConfig
from jointseg.pipeline.outputs import annotate
seen = {}
def timed(module, name, stage):
    fn = getattr(module, name, None)
    if fn is None:
        return
    def wrapper(*a, **k):
        w, c = time.perf_counter(), time.process_time()
        try:
            return fn(*a, **k)
        finally:
            got = seen.setdefault(stage, [0.0, 0.0])
            got[0] += time.perf_counter() - w
            got[1] += time.process_time() - c
    setattr(module, name, wrapper)
for module, name, stage in [
    (stages, "_frame_stage", "frame"), (sbs, "segment", "geometry"),
    (stages, "_fusion_stage", "fusion"), (stages, "_objects_stage", "objects"),
    (stages, "_metrics", "metrics"), (stages, "load_predictor", "load_network"),
]:
    timed(module, name, stage)
try:
    from jointseg.pipeline.quality import with_preset
    body = with_preset({"quality": quality, "concurrent": False})
except ImportError:
    body = {"concurrent": False}
config = PipelineConfig.model_validate(body)
w, c = time.perf_counter(), time.process_time()
scan = jio.read_scan(room)
seen["read"] = [time.perf_counter() - w, time.process_time() - c]
predictor = stages.load_predictor(config.network)
original = predictor.predict
def predict(*a, **k):
    w, c = time.perf_counter(), time.process_time()
    try:
        return original(*a, **k)
    finally:
        got = seen.setdefault("network", [0.0, 0.0])
        got[0] += time.perf_counter() - w
        got[1] += time.process_time() - c
predictor.predict = predict
result = stages.run(scan, config, predictor=predictor)
w, c = time.perf_counter(), time.process_time()
jio.write_scan(annotate(scan, result), room.with_name(room.stem + "_stages.ply"))
seen["write"] = [time.perf_counter() - w, time.process_time() - c]
print(json.dumps(seen))
"""

STAGES = ("load_network", "read", "frame", "network", "geometry", "fusion", "objects",
          "metrics", "write")  # fmt: skip


def _env(cache: Path, code: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(code), "JOINTSEG_CACHE": str(cache)}


def _process(code: Path, room: Path, quality: str, cache: Path) -> dict[str, float]:
    """One ``jointseg segment`` from ``code``: wall, CPU, peak GB and the report's stages."""
    out, rep = room.with_name("out.ply"), room.with_name("report.json")
    cmd = [sys.executable, "-c", PEAK_WRAPPER, sys.executable, "-m", "jointseg", "segment",
           str(room), "-o", str(out), "--quality", quality, "--report", str(rep)]  # fmt: skip
    before = os.times()
    t = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=_env(cache, code), cwd=code)
    wall = time.perf_counter() - t
    after = os.times()
    if done.returncode != 0:
        raise SystemExit(f"{code}: jointseg segment failed:\n{done.stderr[-2000:]}")
    cpu = (after.children_user - before.children_user) + (
        after.children_system - before.children_system
    )
    row = {"wall": wall, "cpu": cpu, "peak": int(done.stderr.strip().splitlines()[-1]) / 1024**2}
    row.update({f"stage:{k}": v for k, v in json.loads(rep.read_text())["timings_s"].items()})
    return row


def _stages(code: Path, room: Path, quality: str, cache: Path) -> dict[str, list[float]]:
    cmd = [sys.executable, "-c", STAGE_CHILD, str(room), quality]
    done = subprocess.run(cmd, capture_output=True, text=True, env=_env(cache, code), cwd=code)
    if done.returncode != 0:
        raise SystemExit(f"{code}: stage run failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _median(rows: list[dict[str, float]], key: str) -> float:
    values = [r[key] for r in rows if key in r]
    return statistics.median(values) if values else float("nan")


def process_part(trees: dict[str, Path], room: Path, presets: list[str], repeats: int,
                 folder: Path) -> None:  # fmt: skip
    runs: dict[tuple[str, str], list[dict[str, float]]] = {}
    for name, code in trees.items():  # warm each tree's cache once, untimed
        _process(code, room, presets[0], folder / f"cache-{name}")
    for _ in range(repeats):
        for preset in presets:
            for name, code in trees.items():
                row = _process(code, room, preset, folder / f"cache-{name}")
                runs.setdefault((name, preset), []).append(row)
    ref = next(iter(trees))
    print(f"\n### Whole process, median of {repeats} ({os.cpu_count()} CPUs)\n")
    print("| code | preset | wall s | vs ref | CPU s | peak GB |\n|---|---|---|---|---|---|")
    for (name, preset), rows in runs.items():
        base = _median(runs.get((ref, preset), runs[(ref, presets[0])]), "wall")
        wall = _median(rows, "wall")
        print(f"| {name} | {preset} | {wall:.2f} | {wall / base:.2f}x | "
              f"{_median(rows, 'cpu'):.2f} | {max(r['peak'] for r in rows):.2f} |")  # fmt: skip
    keys = [k for k in runs[(ref, presets[0])][0] if k.startswith("stage:")]
    for (_, _), rows in runs.items():
        keys += [k for k in rows[0] if k.startswith("stage:") and k not in keys]
    print("\nThe reports' stage wall seconds (network and geometry side by side):\n")
    names = [k.split(":", 1)[1] for k in keys]
    print("| code | preset | " + " | ".join(names) + " |")
    print("|---|---|" + "---|" * len(names))
    for (name, preset), rows in runs.items():
        cells = " | ".join(f"{_median(rows, k):.2f}" for k in keys)
        print(f"| {name} | {preset} | {cells} |")


def stages_part(trees: dict[str, Path], room: Path, presets: list[str], repeats: int,
                folder: Path) -> None:  # fmt: skip
    runs: dict[tuple[str, str], list[dict[str, list[float]]]] = {}
    for _ in range(repeats):
        for preset in presets:
            for name, code in trees.items():
                got = _stages(code, room, preset, folder / f"cache-{name}")
                runs.setdefault((name, preset), []).append(got)
    print(f"\n### Stage by stage, one after the other in one process, median of {repeats}\n")
    print("wall / CPU seconds (CPU: every thread of the process)\n")
    print("| code | preset | " + " | ".join(STAGES) + " | sum |")
    print("|---|---|" + "---|" * (len(STAGES) + 1))
    for (name, preset), rows in runs.items():
        cells, wall_sum, cpu_sum = [], 0.0, 0.0
        for stage in STAGES:
            walls = [r[stage][0] for r in rows if stage in r]
            cpus = [r[stage][1] for r in rows if stage in r]
            if not walls:
                cells.append("-")
                continue
            w, c = statistics.median(walls), statistics.median(cpus)
            wall_sum, cpu_sum = wall_sum + w, cpu_sum + c
            cells.append(f"{w:.2f} / {c:.2f}")
        print(f"| {name} | {preset} | {' | '.join(cells)} | {wall_sum:.2f} / {cpu_sum:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", default="11aad11", help="the older commit (any git revision)")
    ap.add_argument("--presets", default="standard,fast")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--part", choices=("all", "process", "stages"), default="all")
    args = ap.parse_args()
    presets = args.presets.split(",")
    sha = subprocess.run(["git", "rev-parse", "--short", args.ref], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout.strip()  # fmt: skip
    head = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout.strip()  # fmt: skip
    header(f"`jointseg segment` speed: {sha} against the working tree ({head})")
    with tempfile.TemporaryDirectory(prefix="jointseg-speed-") as tmp:
        folder = Path(tmp)
        room = folder / "room.ply"
        subprocess.run([sys.executable, "-m", "jointseg", "synth", "--seed", "0", "--points",
                        str(args.points), "-o", str(room)], check=True, capture_output=True,
                       cwd=ROOT)  # fmt: skip
        old = folder / f"tree_{sha}"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(old), sha], cwd=ROOT,
                       check=True)  # fmt: skip
        trees = {sha: old, head: ROOT}
        try:
            if args.part in ("all", "process"):
                process_part(trees, room, presets, args.repeats, folder)
            if args.part in ("all", "stages"):
                stages_part(trees, room, presets, args.repeats, folder)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=ROOT,
                           check=False, capture_output=True)  # fmt: skip
    print(f"\nroom: jointseg synth --seed 0 --points {args.points}")


if __name__ == "__main__":
    main()
