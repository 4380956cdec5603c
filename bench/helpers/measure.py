"""Time and memory measures of the benchmarks; standard library only, so that a script measuring
its own memory loads nothing through this module."""

from __future__ import annotations

import resource
import time
from collections.abc import Callable

#: ``python -c PEAK_WRAPPER cmd...``: runs ``cmd`` and prints the peak RSS (KiB) of that child
#: alone on its last stderr line, so each run is measured by itself.
PEAK_WRAPPER = (
    "import resource, subprocess, sys; "
    "code = subprocess.run(sys.argv[1:]).returncode; "
    "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); "
    "sys.exit(code)"
)


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def best_time(fn: Callable[[], object], repeats: int) -> float:
    """Best wall time (s) of ``repeats`` calls of ``fn``."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best
