"""Real scans as users deliver them (issue 31): axes, units, frames, tilt, strays, colour, noise.

Each room goes in other axis conventions, units and frames, tilted, with stray points, without
or with poor colour, noisier, or as one depth camera's view in the camera's frame
(bench/helpers/deliveries.py), made in memory from the clean
labelled room (default: the judging rooms, never trained or tuned on: area6_office_4,
scene0002_00/01, scene0005_00/01, scene0007_00), written to a real file without its ground
truth (PLY, or LAS 1.4 with scale, offsets and a WKT CRS), and segmented as a user would:
`jointseg segment IN -o OUT.ply --report REPORT.json` in a subprocess, with defaults (no
JOINTSEG_ variable of this process reaches it). The output is read back and matched to the
ground truth by point order (outputs keep the input's order); mIoU (jointseg.metrics: classes
in ground truth or prediction, -1 ignored, added stray points ignored) of ``fused_label`` and
``network_label``. ``coords exact``: the output's coordinates equal those stored in the input
file (read back with plyfile/laspy, in the file's own units and frame). ``frame``: the report's
frame section (up, units, tilt, strays) where there is one, beside the truth.

Per variant and dataset: mean over scans (as bench/fusion_real.py) of fused and network mIoU,
a failed run (crash, timeout, unusable output) counting 0; "kept" is that mean over the clean
variant's mean (clean always runs, as the baseline).

    .venv/bin/python bench/real_world.py [--variants clean,yup,mm] [--scans judging|tuning|all|
        NAME,...] [--per-scan] [--jobs 1] [--workdir DIR] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import zlib
from collections import Counter
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from helpers.deliveries import VARIANTS, Delivery, deliver, file_xyz, write_delivery
from helpers.inputs import AREA6, SCANNET
from helpers.report import header

from jointseg.io import read_scan
from jointseg.metrics import evaluate
from jointseg.pipeline.tables import format_score as fmt
from jointseg.scan import Scan

JOINTSEG = str(Path(sys.executable).parent / "jointseg")
#: Rooms never trained or tuned on (ScanNet: the bundled network's held-out rooms).
JUDGING = (
    "area6_office_4",
    "scene0002_00",
    "scene0002_01",
    "scene0005_00",
    "scene0005_01",
    "scene0007_00",
)
#: A few other rooms to try changes on before judging.
TUNING = ("area6_office_1", "area6_office_12", "area6_copyRoom_1", "scene0001_00", "scene0003_00")
DATASETS = {AREA6.name: "S3DIS", SCANNET.name: "ScanNet"}
#: Report frame keys shown, and their short names.
FRAME_KEYS = (
    ("up", "up"),
    ("units", "units"),
    ("tilt_degrees", "tilt"),
    ("stray_points", "strays"),
)


@dataclass
class Run:
    """One scan x variant: the delivered file, the CLI run and its scores."""

    scan: str
    dataset: str
    variant: str
    file: str
    points: int
    truth: dict[str, Any]
    status: str = "ok"  # ok, crash, timeout, bad output
    error: str = ""
    seconds: float = 0.0  # wall time of the CLI process
    pipeline_s: float | None = None  # the report's timings_s.total
    fused: float | None = None
    network: float | None = None
    coords_exact: bool | None = None
    coords_err: float | None = None  # max |output - input file| over all coordinates
    frame: Any = None  # the report's frame section, as written


@dataclass
class Job:
    path: Path
    dataset: str
    variant: str
    scan: Scan = field(repr=False)


def resolve_scans(spec: str) -> list[Path]:
    """``judging``, ``tuning``, ``all`` or comma-separated room names or file paths."""
    if spec == "all":
        return sorted(AREA6.glob("*.ply")) + sorted(SCANNET.glob("*.ply"))
    names = {"judging": JUDGING, "tuning": TUNING}.get(spec) or tuple(spec.split(","))
    paths = []
    for name in names:
        candidates = [Path(name), AREA6 / f"{name}.ply", SCANNET / f"{name}.ply"]
        found = next((p for p in candidates if p.is_file()), None)
        if found is None:
            raise SystemExit(f"no scan {name!r} (looked in {AREA6} and {SCANNET})")
        paths.append(found)
    return paths


def seed_for(seed: int, scan: str, variant: str) -> np.random.Generator:
    """A generator fixed by the seed, the scan and the variant (not by the order of runs)."""
    return np.random.default_rng([seed, zlib.crc32(scan.encode()), zlib.crc32(variant.encode())])


def child_env(jobs: int) -> dict[str, str]:
    """This process's environment without JOINTSEG_ variables (the CLI's defaults); with
    parallel jobs, the CPU threads shared out between them."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("JOINTSEG_")}
    if jobs > 1 and "OMP_NUM_THREADS" not in env:
        env["OMP_NUM_THREADS"] = str(max(1, (os.cpu_count() or 1) // jobs))
    return env


def last_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1][:300] if lines else "(no stderr)"


def plain(value: Any) -> Any:
    """``value`` with numpy arrays and scalars made JSON-ready."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def run_one(job: Job, folder: Path, seed: int, env: dict[str, str], timeout: float) -> Run:
    """Deliver ``job``'s scan as its variant, segment the file with the CLI, score the output."""
    stem = job.path.stem
    scan = job.scan
    assert scan.labels is not None
    variant = VARIANTS[job.variant]
    d: Delivery = deliver(variant.steps, scan.xyz, scan.rgb, seed_for(seed, stem, job.variant))
    gt = np.where(d.source >= 0, scan.labels[np.maximum(d.source, 0)], -1)
    folder.mkdir(parents=True, exist_ok=True)
    src = write_delivery(d, folder / job.variant, variant)
    written = file_xyz(src)
    out, rep = folder / f"{job.variant}.out.ply", folder / f"{job.variant}.report.json"
    truth = {k: d.info[k] for k in ("up_axis", "tilt_degrees", "units", "strays", "colour")}
    run = Run(stem, job.dataset, job.variant, str(src), len(d.xyz), plain(truth))
    cmd = [JOINTSEG, "segment", str(src), "-o", str(out), "--report", str(rep)]
    t = time.perf_counter()
    try:
        proc = subprocess.run(
            cmd, capture_output=True, text=True, errors="replace", env=env, timeout=timeout
        )
    except subprocess.TimeoutExpired:
        run.seconds = time.perf_counter() - t
        run.status, run.error = "timeout", f"no result after {timeout:.0f} s"
        return run
    run.seconds = time.perf_counter() - t
    (folder / f"{job.variant}.stderr.txt").write_text(proc.stderr)
    if proc.returncode != 0:
        run.status = "crash"
        run.error = f"exit {proc.returncode}: {last_line(proc.stderr)}"
        return run
    if rep.is_file():
        report = json.loads(rep.read_text())
        run.frame = report.get("frame")
        run.pipeline_s = report.get("timings_s", {}).get("total")
    try:
        result = read_scan(out)
    except Exception as exc:  # noqa: BLE001 - whatever the output is, the bench reports it
        run.status, run.error = "bad output", f"cannot read {out.name}: {exc}"
        return run
    if len(result) != len(gt):
        run.status = "bad output"
        run.error = f"output has {len(result):,} points, input {len(gt):,}"
        return run
    missing = [f for f in ("fused_label", "network_label") if f not in result.fields]
    if missing:
        run.status, run.error = "bad output", f"output lacks {', '.join(missing)}"
        return run
    run.fused = evaluate(gt, result.fields["fused_label"]).miou or 0.0
    run.network = evaluate(gt, result.fields["network_label"]).miou or 0.0
    run.coords_exact = bool(np.array_equal(result.xyz, written))
    run.coords_err = float(np.abs(result.xyz - written).max()) if len(written) else 0.0
    return run


# --- tables --------------------------------------------------------------------------------


def compact(value: Any) -> str:
    """A report value in a few characters."""
    if isinstance(value, bool) or value is None:
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, int | str):
        return str(value)
    if isinstance(value, list | tuple) and all(isinstance(v, int | float) for v in value):
        return "(" + ",".join(f"{float(v):.2f}" for v in value) + ")"
    if isinstance(value, dict):
        for key in ("axis", "name", "decided", "value", "count"):
            if key in value:
                return compact(value[key])
    return json.dumps(value, separators=(",", ":"))[:30]


def frame_text(frame: Any) -> str:
    """The report's frame section as ``up=+y units=mm tilt=0.3 strays=12`` ('-' if none)."""
    if not isinstance(frame, dict) or not frame:
        return "-"
    up, units = frame.get("up"), frame.get("units")
    if isinstance(up, dict) and isinstance(units, dict):  # the frame stage's own report
        text = f"up={up.get('axis')} ({up.get('confidence', 0):.2f}) units={units.get('unit')}"
        if up.get("levelled"):
            text += f" tilt={up.get('tilt_degrees', 0):.0f}"
        return text + f" strays={frame.get('stray_points', 0)}"
    parts = [f"{short}={compact(frame[key])}" for key, short in FRAME_KEYS if key in frame]
    return " ".join(parts) if parts else json.dumps(frame, separators=(",", ":"))[:40]


def truth_text(truth: dict[str, Any]) -> str:
    text = f"up={truth['up_axis']}"
    if truth["tilt_degrees"] > 0.5:
        text += f" tilt={truth['tilt_degrees']:.0f}"
    text += f" units={truth['units']}"
    if truth["strays"]:
        text += f" strays={truth['strays']}"
    return text


def score(run: Run | None) -> float:
    """A run's fused mIoU, 0 when it failed."""
    return run.fused if run is not None and run.fused is not None else 0.0


def per_scan_table(runs: list[Run], clean: dict[str, Run]) -> str:
    head = (
        "| scan | dataset | variant | points | fused | kept | network | s | coords exact | "
        "frame (report) | truth | status |"
    )
    lines = [head, "|---" * 12 + "|"]
    for r in runs:
        base = score(clean.get(r.scan))
        kept = f"{100 * score(r) / base:.0f}%" if base > 0 else "/"
        exact = "-" if r.coords_exact is None else ("yes" if r.coords_exact else "NO")
        if r.coords_exact is False:
            exact += f" ({r.coords_err:.3g})"
        lines.append(
            f"| {r.scan} | {r.dataset} | {r.variant} | {r.points:,} | {fmt(r.fused)} | {kept} | "
            f"{fmt(r.network)} | {r.seconds:.1f} | {exact} | {frame_text(r.frame)} | "
            f"{truth_text(r.truth)} | {r.status} |"
        )
    return "\n".join(lines)


def summarise(runs: list[Run], variants: list[str]) -> list[dict[str, Any]]:
    """One row per variant x dataset: means over scans (failed runs count 0)."""
    rows = []
    datasets = sorted({r.dataset for r in runs})
    for v in variants:
        for ds in datasets:
            sel = [r for r in runs if r.variant == v and r.dataset == ds]
            if not sel:
                continue
            base = [r for r in runs if r.variant == "clean" and r.dataset == ds]
            clean_mean = float(np.mean([score(r) for r in base])) if base else 0.0
            fused = float(np.mean([score(r) for r in sel]))
            ok = [r for r in sel if r.status == "ok"]
            frames = Counter(frame_text(r.frame) for r in ok)
            rows.append(
                {
                    "variant": v,
                    "dataset": ds,
                    "scans": len(sel),
                    "fused": fused,
                    "kept": fused / clean_mean if clean_mean > 0 else None,
                    "network": float(np.mean([r.network or 0.0 for r in sel])),
                    "crashed": len(sel) - len(ok),
                    "coords_exact": sum(bool(r.coords_exact) for r in ok),
                    "scored": len(ok),
                    "seconds": float(np.mean([r.seconds for r in sel])),
                    "frame": "; ".join(
                        f"{text} x{n}" if len(frames) > 1 else text
                        for text, n in frames.most_common()
                    )
                    or "-",
                    "truth": truth_text(sel[0].truth),
                }
            )
    return rows


def summary_table(rows: list[dict[str, Any]]) -> str:
    head = (
        "| variant | dataset | scans | fused mIoU | kept | network mIoU | crashed | "
        "coords exact | s / run | frame (report) | truth |"
    )
    lines = [head, "|---" * 11 + "|"]
    for r in rows:
        kept = "/" if r["kept"] is None else f"{100 * r['kept']:.0f}%"
        lines.append(
            f"| {r['variant']} | {r['dataset']} | {r['scans']} | {r['fused']:.3f} | {kept} | "
            f"{r['network']:.3f} | {r['crashed']} | {r['coords_exact']}/{r['scored']} | "
            f"{r['seconds']:.1f} | {r['frame']} | {r['truth']} |"
        )
    return "\n".join(lines)


# --- main ----------------------------------------------------------------------------------


def parse_variants(text: str) -> list[str]:
    names = [v.strip() for v in text.split(",") if v.strip()] if text != "all" else list(VARIANTS)
    unknown = [v for v in names if v not in VARIANTS]
    if unknown:
        raise SystemExit(f"unknown variants {unknown}; known: {', '.join(VARIANTS)}")
    return ["clean"] + [v for v in dict.fromkeys(names) if v != "clean"]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__.splitlines()[0],
        epilog="variants: " + "; ".join(f"{name}: {v.what}" for name, v in VARIANTS.items()),
    )
    parser.add_argument(
        "--variants", default="all", help="comma-separated (or all); clean always runs"
    )
    parser.add_argument(
        "--scans", default="judging", help="judging, tuning, all, or comma-separated names/paths"
    )
    parser.add_argument("--per-scan", action="store_true", help="print a row per scan x variant")
    parser.add_argument("--workdir", type=Path, help="keep inputs, outputs and reports here")
    parser.add_argument("--json", type=Path, help="write every run and the summary here")
    parser.add_argument("--jobs", type=int, default=1, help="CLI processes at once")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random variants")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds per CLI run")
    args = parser.parse_args()
    header()
    variants = parse_variants(args.variants)
    paths = resolve_scans(args.scans)
    env = child_env(args.jobs)
    jobs: list[Job] = []
    for path in paths:
        scan = read_scan(path)
        if scan.labels is None:
            raise SystemExit(f"{path}: no label field")
        dataset = DATASETS.get(path.parent.name, path.parent.name)
        jobs += [Job(path, dataset, v, scan) for v in variants]
    tmp = None if args.workdir else tempfile.TemporaryDirectory(prefix="real_world-")
    work = args.workdir or Path(tmp.name if tmp else ".")
    runs: list[Run] = []
    t0 = time.perf_counter()
    try:
        with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
            futures = {
                pool.submit(run_one, j, work / j.path.stem, args.seed, env, args.timeout): j
                for j in jobs
            }
            for fut in as_completed(futures):
                run = fut.result()
                runs.append(run)
                print(
                    f"[{len(runs)}/{len(jobs)}] {run.scan} {run.variant}: {run.status} "
                    f"{run.seconds:.1f} s, fused {fmt(run.fused)} {run.error}",
                    file=sys.stderr,
                )
    finally:
        if tmp is not None:
            tmp.cleanup()
    order = {(j.path.stem, j.variant): i for i, j in enumerate(jobs)}
    runs.sort(key=lambda r: (variants.index(r.variant), r.dataset, order[(r.scan, r.variant)]))
    clean = {r.scan: r for r in runs if r.variant == "clean"}
    rows = summarise(runs, variants)
    print(
        f"\n## real-world deliveries ({time.strftime('%F')}): {len(paths)} scans "
        f"({args.scans}), {len(variants)} variants, {len(runs)} runs in "
        f"{time.perf_counter() - t0:.0f} s, --jobs {args.jobs}\n"
    )
    if args.per_scan:
        print(per_scan_table(runs, clean))
        print()
    print(summary_table(rows))
    print(
        "\nmIoU: mean over the dataset's scans, a failed run counting 0; kept: over clean's mean; "
        "coords exact: runs whose output coordinates equal the input file's / runs scored."
    )
    failed = [r for r in runs if r.status != "ok"]
    if failed:
        print("\nfailed runs:")
        for r in failed:
            print(f"- {r.scan} {r.variant}: {r.status}: {r.error}")
    if args.json:
        payload = {
            "date": time.strftime("%F %T"),
            "scans": [str(p) for p in paths],
            "variants": {v: VARIANTS[v].what for v in variants},
            "seed": args.seed,
            "summary": rows,
            "runs": [plain(asdict(r)) for r in runs],
        }
        args.json.write_text(json.dumps(payload, indent=1))


if __name__ == "__main__":
    main()
