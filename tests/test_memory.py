"""release_memory hands a big run's freed heap back, so what comes next does not add on top."""

from __future__ import annotations

import sys

import numpy as np
import psutil
import pytest

from jointseg.memory import release_memory


def _resident_mb() -> float:
    return float(psutil.Process().memory_info().rss) / 2**20


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim: Linux")
def test_freed_small_arrays_go_back_to_the_system() -> None:
    # 150 000 arrays of 1.6 kB: below glibc's mmap threshold, so they live on the heap
    arrays = [np.ones(200) for _ in range(150_000)]
    arrays = arrays[-1:]  # all but one freed: glibc keeps the pages
    held = _resident_mb()
    assert release_memory()
    assert _resident_mb() < held - 100, (held, _resident_mb())
    assert arrays[0].sum() == 200
