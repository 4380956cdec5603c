"""Quality presets (issue 34): what fast, standard and best cost and give.

Speed: ``jointseg segment`` on the 1 M-point room (``jointseg synth --seed 1501 --points
1000000``) as a user types it, each in a fresh process: whole-process seconds (median of
--repeats) and peak resident memory, for every preset and for the old code (``--baseline-ref``,
checked out into a temporary git worktree) run in the same command; speed is its ratio to
the old code's.

Accuracy: network and fused mIoU of each preset (``jointseg.pipeline.run``) on the judging
scans, which no preset was tuned on: the first 10 S3DIS Area_6 rooms in name-hash order
(bench/helpers/scans.py's split) and ScanNet's scene0002, 0005 and 0007; the tuning scans are
printed apart. best averages in DGCNN only where its weights are on this machine (``jointseg
models pull``, or JOINTSEG_DGCNN_WEIGHTS); the table says which networks ran.

    .venv/bin/python bench/presets.py [--part speed|accuracy|all] [--presets fast,standard,best]
        [--repeats 3] [--baseline-ref 9a93392] [--splits judging|tuning|all]
        [--engines torch,openvino]
    .venv/bin/python bench/presets.py --part fusion [--splits tuning]

``--part fusion`` runs best once per scan and then its vote under other fusion settings, to
see whether a vote suited to the ensemble's probabilities adds what best lacks on S3DIS.
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
from typing import Any

import numpy as np
from helpers.measure import PEAK_WRAPPER
from helpers.report import header

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = ROOT.parent / "shared" / "data"
SCANNET_JUDGES = ("scene0002", "scene0005", "scene0007")


def _segment(
    code: Path, room: Path, out: Path, quality: str | None, config: Path | None = None
) -> tuple[float, float]:
    """Whole-process seconds and peak GB of ``jointseg segment`` from the tree ``code``."""
    cmd = [sys.executable, "-c", PEAK_WRAPPER, sys.executable, "-m", "jointseg", "segment"]
    cmd += [str(room), "-o", str(out)] + ([] if quality is None else ["--quality", quality])
    cmd += [] if config is None else ["--config", str(config)]
    env = {**os.environ, "PYTHONPATH": str(code), "JOINTSEG_CACHE": str(out.parent / "cache")}
    t = time.perf_counter()
    # run from the tree itself: ``python -m`` puts the working folder first on sys.path
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=code, check=False)
    wall = time.perf_counter() - t
    if done.returncode != 0:
        raise SystemExit(f"{code}: jointseg segment failed:\n{done.stderr[-2000:]}")
    return wall, int(done.stderr.strip().splitlines()[-1]) / 1024**2


def speed_part(presets: list[str], repeats: int, ref: str, engines: list[str]) -> None:
    with tempfile.TemporaryDirectory(prefix="jointseg-presets-") as tmp:
        folder = Path(tmp)
        room = folder / "room.ply"
        subprocess.run(
            [sys.executable, "-m", "jointseg", "synth", "--seed", "1501", "--points", "1000000",
             "-o", str(room)], check=True, capture_output=True,
        )  # fmt: skip
        old = folder / "old"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(old), ref], check=True
        )
        configs = {e: _engine_config(folder, e) for e in engines}
        try:
            runs: dict[str, list[tuple[float, float]]] = {}
            if "openvino" in engines:  # the first run exports and compiles: timed apart
                first = _segment(ROOT, room, folder / "o.ply", presets[0], configs["openvino"])
                print(f"first openvino run (cold cache), {presets[0]}: {first[0]:.2f} s")
            for _ in range(repeats):  # interleaved, so a slow spell of the machine hits all
                runs.setdefault("old", []).append(_segment(old, room, folder / "o.ply", None))
                for name in presets:
                    for engine in engines:
                        label = name if engine == "torch" else f"{name}, {engine}"
                        got = _segment(ROOT, room, folder / "o.ply", name, configs[engine])
                        runs.setdefault(label, []).append(got)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old)])
    base = statistics.median(w for w, _ in runs["old"])
    print(f"\nSpeed: jointseg segment, 1 M-point room, median of {repeats}, {os.cpu_count()} CPUs,"
          f" old code = {ref}\n")  # fmt: skip
    print("| code | whole process s | vs old | peak GB |\n|---|---|---|---|")
    for name, rows in runs.items():
        wall = statistics.median(w for w, _ in rows)
        peak = max(p for _, p in rows)
        label = f"old ({ref})" if name == "old" else name
        print(f"| {label} | {wall:.2f} | {wall / base:.2f}x | {peak:.2f} |")


def _engine_config(folder: Path, engine: str) -> Path | None:
    """A config file choosing RandLA-Net's CPU engine (None: the default, torch)."""
    if engine == "torch":
        return None
    path = folder / f"{engine}.json"
    path.write_text(json.dumps({"network": {"randlanet": {"engine": engine}}}))
    return path


def _scans(split: str) -> dict[str, list[Path]]:
    from jointseg.training.data import stable_order

    out: dict[str, list[Path]] = {}
    area6 = sorted((DATA / "s3dis_area6").glob("*.ply"))
    judged = set(stable_order([p.stem for p in area6])[:10])
    scannet = sorted((DATA / "scannet").glob("*.ply"))
    for name, judging in (("judging", True), ("tuning", False)):
        if split not in (name, "all"):
            continue
        out[f"S3DIS Area_6 {name}"] = [p for p in area6 if (p.stem in judged) == judging]
        judged_sn = [p for p in scannet if p.stem.startswith(SCANNET_JUDGES) == judging]
        out[f"ScanNet {name}"] = judged_sn
    return {k: v for k, v in out.items() if v}


def accuracy_part(presets: list[str], split: str) -> None:
    from jointseg.io import read_scan
    from jointseg.pipeline import PipelineConfig, load_predictor, run

    sets = _scans(split)
    if not sets:
        print("(../shared/data absent: no accuracy rows)")
        return
    print("\nAccuracy: mean mIoU over the scans (network -> fused), and the networks that ran\n")
    print("| preset | scans | network mIoU | fused mIoU | networks | views | s per scan |")
    print("|---|---|---|---|---|---|---|")
    scans = {name: [read_scan(p) for p in paths] for name, paths in sets.items()}
    for preset in presets:
        config = PipelineConfig.model_validate({"quality": preset})
        predictor = load_predictor(config.network)
        for name, items in scans.items():
            net: list[float] = []
            fused: list[float] = []
            seconds: list[float] = []
            used = ""
            for scan in items:
                t = time.perf_counter()
                result = run(scan, config, predictor=predictor)
                seconds.append(time.perf_counter() - t)
                assert result.metrics is not None
                net.append(result.metrics["network"].miou or 0.0)
                fused.append(result.metrics["fused"].miou or 0.0)
                used = "+".join(result.params["network"]["networks"])
            views = randlanet_views(config)
            print(f"| {preset} | {name} ({len(items)}) | {100 * np.mean(net):.2f} | "
                  f"{100 * np.mean(fused):.2f} | {used} | {views} | {np.mean(seconds):.1f} |",
                  flush=True)  # fmt: skip


def randlanet_views(config: Any) -> object:
    """Test-time views of the config's RandLA-Net section (NetworkConfig's per-backend sections
    are made at run time, out of mypy's sight)."""
    return getattr(getattr(config.network, "randlanet", None), "views", "-")


#: best's fusion settings tried on the tuning scans: does a vote made for the ensemble's
#: smoother probabilities add what the bar asks on S3DIS?
THRESHOLD_TRIALS: list[dict[str, object]] = [
    {"flip_threshold": v} for v in (0.45, 0.5, 0.6, 0.65, 0.7, 0.8)
]
FUSION_TRIALS: list[dict[str, object]] = [
    {},
    *THRESHOLD_TRIALS,
    {"min_support": 0.2},
    {"mode": "evidence"},
    {"mode": "soft"},
    {"mode": "paper"},
]


def fusion_part(split: str) -> None:
    """best's network and geometry once per scan, then the vote under each trial setting, on
    the levelled metric points as the pipeline fuses them (every point, strays included)."""
    from jointseg.fusion import FusionParams, fuse
    from jointseg.io import read_scan
    from jointseg.metrics import evaluate
    from jointseg.pipeline import PipelineConfig, load_predictor, run

    sets = _scans(split)
    if not sets:
        print("(../shared/data absent: no fusion rows)")
        return
    config = PipelineConfig.model_validate({"quality": "best", "objects": {"enabled": False}})
    predictor = load_predictor(config.network)
    rows: dict[str, dict[str, list[float]]] = {}
    used = ""
    for name, paths in sets.items():
        for path in paths:
            scan = read_scan(path)
            result = run(scan, config, predictor=predictor)
            used = "+".join(result.params["network"]["networks"])
            assert scan.labels is not None and result.frame is not None
            xyz = result.frame.to_work(scan.xyz)
            net, geo = result.network, result.geometry
            rows.setdefault("network", {}).setdefault(name, []).append(
                evaluate(scan.labels, net.labels).miou or 0.0
            )
            for trial in FUSION_TRIALS:
                params = FusionParams.model_validate({**config.fusion.model_dump(), **trial})
                fused = fuse(xyz, geo.segments, net.labels, net.probs, params,
                             main_plane=geo.main_plane)  # fmt: skip
                key = ", ".join(f"{k} {v}" for k, v in trial.items()) or "default (learned)"
                rows.setdefault(key, {}).setdefault(name, []).append(
                    evaluate(scan.labels, fused.labels).miou or 0.0
                )
    names = list(sets)
    print(f"\nbest's vote ({used}, {randlanet_views(config)} views): mean mIoU\n")
    print("| fusion setting | " + " | ".join(names) + " |")
    print("|---|" + "---|" * len(names))
    for key, by_set in rows.items():
        cells = " | ".join(f"{100 * np.mean(by_set[n]):.2f}" for n in names)
        print(f"| {key} | {cells} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--part", choices=("speed", "accuracy", "fusion", "all"), default="all",
        help="fusion: best's vote settings on --splits (default tuning; not part of all)",
    )  # fmt: skip
    parser.add_argument("--presets", default="fast,standard,best")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline-ref", default="9a93392", help="git ref of the old code")
    parser.add_argument("--splits", choices=("judging", "tuning", "all"), default=None)
    parser.add_argument(
        "--engines", default="torch",
        help="RandLA-Net's CPU engines timed in the speed part, e.g. torch,openvino",
    )  # fmt: skip
    args = parser.parse_args()
    header()
    presets = [p for p in args.presets.split(",") if p]
    print(f"# quality presets, {time.strftime('%F')}")
    if args.part in ("speed", "all"):
        speed_part(presets, args.repeats, args.baseline_ref, args.engines.split(","))
    if args.part in ("accuracy", "all"):
        accuracy_part(presets, args.splits or "all")
    if args.part == "fusion":
        fusion_part(args.splits or "tuning")


if __name__ == "__main__":
    main()
