"""Chunked scan I/O (jointseg.io.stream) against whole-scan I/O: peak memory and time.

A synthetic floor (``jointseg.synth.make_floor``, ~5 M points by default) is written once as
LAZ, LAS and PLY (cached in bench/_cache). Each row then runs in a fresh Python process that
reports its own peak resident memory (VmHWM, which counts the pages of memory-mapped files
too) and wall-clock time, so rows do not share allocator state. "baseline" is such a process
that only imports the readers; "above baseline" is what reading or copying the scan cost.

    .venv/bin/python bench/stream_io.py [--points 5000000] [--chunk 1000000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from helpers.report import header

CACHE = Path(__file__).resolve().parent / "_cache"

#: The child process: runs one mode and prints {"s": seconds, "rss_mb": peak RSS}.
CHILD = r"""
import json, resource, sys, time
import numpy as np
from jointseg.io import read_scan, write_scan
from jointseg.io.stream import open_chunks, open_writer

mode, src, out, chunk = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
t = time.perf_counter()
if mode == "whole_read":
    read_scan(src, max_points=10**9)
elif mode == "chunk_read":
    with open_chunks(src, max_points=10**9) as source:
        for part in source.chunks(chunk):
            pass
elif mode == "whole_copy":
    write_scan(read_scan(src, max_points=10**9), out)
elif mode == "chunk_copy":
    with open_chunks(src, max_points=10**9) as source:
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for part in source.chunks(chunk):  # a pass for the bounds, as a tiled pipeline has
            lo = np.minimum(lo, part.xyz.min(axis=0))
            hi = np.maximum(hi, part.xyz.max(axis=0))
        like = next(source.chunks(1))
        with open_writer(out, count=source.count, like=like, bounds=(lo, hi)) as sink:
            for part in source.chunks(chunk):
                sink.write(part)
seconds = time.perf_counter() - t
try:  # VmHWM: the peak of this program; ru_maxrss would carry the parent's over execve
    status = open("/proc/self/status").read()
    rss_mb = int(status.split("VmHWM:")[1].split()[0]) / 1024
except (OSError, IndexError):
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"s": seconds, "rss_mb": rss_mb}))
"""


def make_inputs(points: int) -> dict[str, Path]:
    """The cached synthetic floor as LAZ, LAS and PLY (written by jointseg's own writers)."""
    CACHE.mkdir(exist_ok=True)
    paths = {ext: CACHE / f"stream_io_floor_{points}.{ext}" for ext in ("laz", "las", "ply")}
    if not all(p.exists() for p in paths.values()):
        from jointseg.io import write_scan
        from jointseg.synth import make_floor

        scan = make_floor(1, rooms=max(2, round(points / 700_000)), points=points)
        for path in paths.values():
            write_scan(scan, path)
    return paths


def run(mode: str, src: Path, out: Path, chunk: int) -> dict[str, float]:
    """One mode in a fresh process."""
    cmd = [sys.executable, "-c", CHILD, mode, str(src), str(out), str(chunk)]
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=5_000_000)
    parser.add_argument("--chunk", type=int, default=1_000_000)
    args = parser.parse_args()
    header()
    paths = make_inputs(args.points)
    out_dir = CACHE / "stream_io_out"
    out_dir.mkdir(exist_ok=True)
    base = run("baseline", paths["laz"], out_dir / "x", args.chunk)
    print(
        f"# chunked scan I/O, {args.points:,} points, chunks of {args.chunk:,}, "
        f"{time.strftime('%F')}, {os.cpu_count()} CPUs\n"
    )
    print(f"baseline process (imports only): {base['rss_mb']:.0f} MB\n")
    print("| file | what | s | peak RSS MB | above baseline MB |")
    print("|---|---|---|---|---|")
    rows = [
        ("laz", "whole_read", "read_scan"),
        ("laz", "chunk_read", "open_chunks, iterate"),
        ("laz", "whole_copy", "read_scan + write_scan (LAZ)"),
        ("laz", "chunk_copy", "open_chunks + open_writer (LAZ)"),
        ("las", "whole_read", "read_scan"),
        ("las", "chunk_read", "open_chunks, iterate"),
        ("ply", "whole_read", "read_scan"),
        ("ply", "chunk_read", "open_chunks, iterate"),
        ("ply", "whole_copy", "read_scan + write_scan (PLY)"),
        ("ply", "chunk_copy", "open_chunks + open_writer (PLY)"),
    ]
    for ext, mode, label in rows:
        row = run(mode, paths[ext], out_dir / f"out.{ext}", args.chunk)
        print(
            f"| {ext} | {label} | {row['s']:.1f} | {row['rss_mb']:.0f} | "
            f"{row['rss_mb'] - base['rss_mb']:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
