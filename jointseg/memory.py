"""Handing freed heap memory back to the operating system: the project's one ``malloc_trim``.

After a big run, glibc keeps the freed heap in its free lists (and what other threads freed in
their arenas): the process's resident set stays near its peak, and whatever comes next (an IFC
model, the next job in a worker, the next result a viewer opens) adds on top. The CLI calls
:func:`release_memory` between a run and its objects; the viewer (``web.memory``) a moment after
a tab closes.
"""

from __future__ import annotations

import ctypes
import gc
import logging
from collections.abc import Callable

log = logging.getLogger(__name__)


def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim`` among the symbols already loaded, None elsewhere (musl, macOS,
    Windows). Looked up once: ``ctypes.util.find_library`` would run ldconfig on every call."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError, TypeError):
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim  # type: ignore[no-any-return]


_TRIM = _malloc_trim()


def can_release() -> bool:
    """Whether this process's malloc can give freed heap back (glibc's)."""
    return _TRIM is not None


def release_memory() -> bool:
    """Free unreachable reference cycles (a closed viewer tab's handles form some), then give the
    heap's free pages back; True when some went back, False when none did or malloc cannot."""
    gc.collect()
    if _TRIM is None:
        return False
    return bool(_TRIM(0))
