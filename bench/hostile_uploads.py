"""API peak memory under hostile uploads (issue 44, point 1): three at once of each kind.

Starts `jointseg serve` (no workers: nothing is run) on a free loopback port, then for each
hostile kind (a LAZ whose header claims 40 M points, a 0.5 MB NPZ inflating to 480 MB, PLY and
PCD headers claiming 40 M points; made by tests/support/hostile_files.py) resets the API
process's peak resident memory (``/proc/<pid>/clear_refs``), posts the file three times at once
and prints the answers, the time and how far the peak (VmHWM) rose above the resident memory
before. The service's checks keep that within 300 MB.

    .venv/bin/python bench/hostile_uploads.py
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
from helpers.report import header
from helpers.service import start_service

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.support.hostile_files import CLAIMED, HOSTILE  # noqa: E402 - the tests' own files

log = logging.getLogger("bench.hostile_uploads")


def _status_mb(pid: int, key: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(f"{key}:"):
            return int(line.split()[1]) / 1024
    raise KeyError(key)


def _post(url: str, path: Path) -> int:
    with open(path, "rb") as fh:
        answer = httpx.post(f"{url}/v1/jobs", files={"file": (path.name, fh)}, timeout=300)
    return answer.status_code


def main() -> None:
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--concurrent", type=int, default=3, help="uploads at once per kind")
    args = parser.parse_args()
    header()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        files = {kind: make(folder) for kind, make in HOSTILE.items()}
        data = folder / "data"
        data.mkdir()
        proc, url = start_service(data, 0, wait_s=180)
        try:
            time.sleep(3)  # the checking process the API starts
            rows = []
            for kind, path in files.items():
                Path(f"/proc/{proc.pid}/clear_refs").write_text("5")
                before = _status_mb(proc.pid, "VmRSS")
                began = time.monotonic()
                with ThreadPoolExecutor(args.concurrent) as pool:
                    codes = list(pool.map(lambda _, p=path: _post(url, p), range(args.concurrent)))
                took = time.monotonic() - began
                growth = _status_mb(proc.pid, "VmHWM") - before
                rows.append((kind, path.stat().st_size, codes, took, before, growth))
        finally:
            proc.terminate()
            proc.wait(60)
    print(f"{args.concurrent} concurrent uploads of each kind, each claiming {CLAIMED:,} points")
    print("| kind | file bytes | answers | seconds | API RSS before (MB) | API peak growth (MB) |")
    print("|---|---:|---|---:|---:|---:|")
    for kind, size, codes, took, before, growth in rows:
        answers = " ".join(str(c) for c in codes)
        print(f"| {kind} | {size:,} | {answers} | {took:.2f} | {before:.0f} | {growth:.0f} |")


if __name__ == "__main__":
    main()
