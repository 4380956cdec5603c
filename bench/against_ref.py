"""The product at an older commit against the working tree's, as a user runs it.

An issue's "today's figure" was measured with the code of its day. This bench reads that code
from git (``--ref``: a commit, in a temporary worktree removed afterwards) and runs it beside the
working tree's, on the same scans: ``jointseg segment IN -o OUT.ply`` in a subprocess, with
defaults (no JOINTSEG_ variable reaches it), each tree's own package, bundled network and vote
model on the path (the same virtual environment). ``--up auto`` lets the scan decide its frame,
as a new user's run does; ``--up +z`` forces the frame right, as bench/structure.py does.

Per tree: pooled per-class IoU, mIoU over the classes in the truth (bench/structure.py's), the
network's and the fused labels', and the mean of the scans' own mIoU.

    .venv/bin/python bench/against_ref.py --ref 200ecb3 [--scans scene0002_00,...]
        [--up auto|+z] [--workdir DIR]

Issue 43's "today" is 200ecb3, the commit before its first change (12af0b6).
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from helpers.inputs import SCANNET
from helpers.report import header
from helpers.scans import SCANNET_JUDGES
from real_world import child_env
from structure import ious, miou

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.io import read_scan
from jointseg.metrics import confusion_matrix

ROOT = Path(__file__).resolve().parents[1]
#: ScanNet's judging scans: every scan of bench/helpers/scans.py's judging rooms.
JUDGING = sorted(p.stem for p in SCANNET.glob("*.ply") if p.stem[:9] in SCANNET_JUDGES)
#: Runs `jointseg segment` from whichever package PYTHONPATH puts first.
CLI = "import sys; from jointseg.cli import main; sys.argv[0] = 'jointseg'; sys.exit(main())"

log = logging.getLogger("against_ref")


def segment(tree: Path, scan: Path, out: Path, up: str) -> dict[str, np.ndarray]:
    """``jointseg segment`` from ``tree``'s package on ``scan``; its network and fused labels."""
    cmd = [sys.executable, "-c", CLI, "segment", str(scan), "-o", str(out)]
    if up != "auto":
        cmd += ["--up", up]
    env = child_env(1) | {"PYTHONPATH": str(tree)}
    proc = subprocess.run(cmd, env=env, cwd=out.parent, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{tree}: segment {scan.name} failed:\n{proc.stderr[-2000:]}")
    fields = read_scan(out).fields
    return {k: np.asarray(fields[f"{k}_label"]).astype(np.int64) for k in ("network", "fused")}


def measure(tree: Path, scans: list[Path], folder: Path, up: str) -> dict[str, list[np.ndarray]]:
    """Per scan, the confusion of the network's and the fused labels."""
    folder.mkdir(parents=True, exist_ok=True)
    out: dict[str, list[np.ndarray]] = {"network": [], "fused": []}
    for path in scans:
        labels = read_scan(path).labels
        assert labels is not None
        got = segment(tree, path, folder / f"{path.stem}.ply", up)
        for k in out:
            out[k].append(confusion_matrix(labels.astype(np.int64), got[k]))
        log.info("%s: %s done", tree.name, path.stem)
    return out


def print_table(results: dict[str, dict[str, list[np.ndarray]]]) -> None:
    present = np.sum(next(iter(results.values()))["fused"], axis=0).sum(1) > 0
    names = [CLASS_NAMES[c] for c in range(NUM_CLASSES) if present[c]]
    print("| code | labels | mIoU | mean of scans | " + " | ".join(names) + " |")
    print("|---" * (4 + len(names)) + "|")
    for code, by_kind in results.items():
        for kind, cms in by_kind.items():
            pooled = np.sum(cms, axis=0)
            per = ious(pooled)[present]
            mean = float(np.mean([miou(cm) for cm in cms]))
            cells = " | ".join(f"{v:.3f}" for v in per)
            print(f"| {code} | {kind} | {miou(pooled):.4f} | {mean:.4f} | {cells} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ref", required=True, help="the older commit (any git revision)")
    ap.add_argument("--scans", default=",".join(JUDGING), help="ScanNet scan names or PLY paths")
    ap.add_argument("--up", default="auto", help="auto (the scan decides) or an axis like +z")
    ap.add_argument("--workdir", type=Path, default=None, help="keep outputs here")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s", stream=sys.stderr)
    scans = [Path(s) if s.endswith(".ply") else SCANNET / f"{s}.ply" for s in args.scans.split(",")]
    missing = [str(p) for p in scans if not p.is_file()]
    if missing:
        raise SystemExit(f"no such scan: {', '.join(missing)}")
    sha = subprocess.run(["git", "rev-parse", "--short", args.ref], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout.strip()  # fmt: skip
    head = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout.strip()  # fmt: skip
    header(f"`jointseg segment` at {sha} against the working tree ({head}), --up {args.up}")
    with tempfile.TemporaryDirectory(prefix="against_ref_") as tmp:
        work = args.workdir or Path(tmp)
        old = Path(tmp) / f"tree_{sha}"
        subprocess.run(["git", "worktree", "add", "--detach", str(old), sha], cwd=ROOT,
                       check=True, capture_output=True)  # fmt: skip
        try:
            results = {
                sha: measure(old, scans, work / sha, args.up),
                head: measure(ROOT, scans, work / "head", args.up),
            }
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=ROOT,
                           check=False, capture_output=True)  # fmt: skip
    print(f"{len(scans)} scans: {', '.join(p.stem for p in scans)}\n")
    print_table(results)


if __name__ == "__main__":
    main()
