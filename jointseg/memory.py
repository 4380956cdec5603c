"""Handing freed memory back to the operating system between the stages of one process.

After a big run, glibc keeps the freed heap in its free lists: the process's resident set stays
near its peak, and whatever comes next (an IFC model, the next job in a worker) adds on top.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging

log = logging.getLogger(__name__)


def release_memory() -> bool:
    """Collect garbage and trim glibc's heap; False where there is no glibc (nothing to do)."""
    gc.collect()
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        trim = ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):  # musl, macOS: no malloc_trim
        return False
    trim.argtypes = [ctypes.c_size_t]
    return bool(trim(0))
