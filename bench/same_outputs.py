"""Fingerprints of everything a refactor must not change: outputs and the API's schema.

Runs `jointseg segment` on a box room, an L-shaped room, a floor and the same floor in tiles,
the library's ``run`` once per fusion variant, and builds the OpenAPI schema; prints a table of
SHA-256 digests. ``--save F`` keeps them; ``--compare F`` exits 1 when any differs::

    .venv/bin/python bench/same_outputs.py --save /tmp/before.json   # on the old commit
    .venv/bin/python bench/same_outputs.py --compare /tmp/before.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from helpers.report import header

JOINTSEG = Path(sys.executable).with_name("jointseg")
SCANS = {  # name: jointseg synth arguments
    "room": ["--seed", "3", "--points", "120000"],
    "room_L": ["--seed", "4", "--points", "120000", "--shape", "L", "--yaw", "25"],
    "floor": ["--seed", "5", "--points", "360000", "--floor", "3"],
}


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def _cli(*args: str) -> None:
    subprocess.run([str(JOINTSEG), *args], check=True, capture_output=True)


#: Report entries that hold seconds, not results.
UNTIMED_KEYS = ("timings_s", "steps_s")


def _untimed(value: object) -> object:
    """``value`` without its timing entries, at any depth."""
    if isinstance(value, dict):
        return {k: _untimed(v) for k, v in value.items() if k not in UNTIMED_KEYS}
    if isinstance(value, list):
        return [_untimed(v) for v in value]
    return value


def _report_digest(path: Path) -> str:
    """The report without its timings and paths (the only things that differ between runs and
    checkouts: the bundled weights are named by their path inside the checkout)."""
    import jointseg

    checkout = str(Path(jointseg.__file__).resolve().parents[1])
    body = json.loads(path.read_text().replace(checkout, "<checkout>"))
    body.pop("input", None)
    body.pop("output", None)
    return _digest(json.dumps(_untimed(body), sort_keys=True).encode())


def segment_runs(work: Path) -> dict[str, str]:
    found: dict[str, str] = {}
    for name, args in SCANS.items():
        _cli("synth", "-o", str(work / f"{name}.ply"), *args)
    runs: dict[str, list[str]] = {name: [] for name in SCANS}
    runs["floor_tiled"] = ["--tile-points", "100000"]
    for name, extra in runs.items():
        source = work / f"{name.removesuffix('_tiled')}.ply"
        out, report = work / f"{name}_out.ply", work / f"{name}_report.json"
        _cli("segment", str(source), "-o", str(out), "--report", str(report), *extra)
        found[f"segment {name}"] = _digest(out.read_bytes())
        found[f"report {name}"] = _report_digest(report)
    return found


def variant_runs(work: Path) -> dict[str, str]:
    import numpy as np

    from jointseg.fusion.variants import VARIANTS
    from jointseg.io import read_scan
    from jointseg.pipeline import PipelineConfig, load_predictor, run

    scan = read_scan(work / "room_L.ply")
    base = PipelineConfig()
    predictor = load_predictor(base.network)
    found = {}
    for name, params in VARIANTS.items():
        result = run(scan, base.model_copy(update={"fusion": params}), predictor=predictor)
        labels = np.ascontiguousarray(result.fused_labels, dtype=np.int64)
        found[f"variant {name}"] = _digest(labels.tobytes())
    return found


def openapi_digest(work: Path) -> dict[str, str]:
    from server.api.app import create_app
    from server.settings import Settings

    app = create_app(Settings(data_dir=work / "data"))
    return {"openapi": _digest(json.dumps(app.openapi(), sort_keys=True).encode())}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--save", type=Path)
    parser.add_argument("--compare", type=Path)
    args = parser.parse_args()
    header()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        found = {**openapi_digest(work), **segment_runs(work), **variant_runs(work)}
    before = json.loads(args.compare.read_text()) if args.compare else {}
    print(f"| {'output':<28} | {'sha256':<16} | {'before':<16} | same |")
    print(f"|{'-' * 30}|{'-' * 18}|{'-' * 18}|------|")
    differ = 0
    for key, value in found.items():
        old = before.get(key, "")
        same = "yes" if old == value else ("-" if not old else "NO")
        differ += same == "NO"
        print(f"| {key:<28} | {value:<16} | {old:<16} | {same:<4} |")
    if args.save:
        args.save.write_text(json.dumps(found, indent=1))
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
