"""Where the benchmarks find their inputs: real scans and models in ../shared (beside the
checkout, read-only), the synthetic-only network in fit/inputs, and cached synthetic floors."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1]
SHARED = BENCH.parents[1] / "shared"
DATA = SHARED / "data"
MODELS = SHARED / "models"
#: The bottom ~1 m of a real S3DIS room, labelled.
FRAGMENT = DATA / "s3dis_fragment.ply"
AREA6 = DATA / "s3dis_area6"
SCANNET = DATA / "scannet"
#: Generated inputs and cached network and geometry outputs (ignored by git).
CACHE = BENCH / "_cache"
#: DGCNN's published S3DIS weights trained without Area_6, as a network spec.
M6 = f"dgcnn:{MODELS / 'dgcnn_s3dis' / 'model_6.t7'}"
#: A weak network: the synthetic-only RandLA-Net (fit/inputs, where the vote's fit reads it).
WEAK = f"randlanet:{BENCH.parent / 'fit' / 'inputs' / 'randlanet_synth.pt'}"
#: Points per synthetic room of a cached floor (a 20 M-point floor has about 28 rooms).
POINTS_PER_ROOM = 700_000


def cached_floor(points: int, folder: Path) -> Path:
    """A synthetic floor of ``points`` points as LAZ in ``folder``, made by the command a user
    types (`jointseg synth --floor`) unless already there."""
    path = folder / f"floor_{points}.laz"
    if not path.exists():
        rooms = min(32, max(2, round(points / POINTS_PER_ROOM)))
        cmd = [sys.executable, "-m", "jointseg", "synth", "-o", str(path), "--floor", str(rooms)]
        cmd += ["--points", str(points), "--seed", "1"]
        subprocess.run(cmd, check=True, capture_output=True, text=True)
    return path
