"""When the viewer hands freed heap back to the system, so its resident memory stays flat.

Each job a tab shows allocates and frees tens of megabytes: the result's sample, the panels'
copies, the messages. viser runs these allocations on its own threads. glibc's malloc keeps the
freed blocks in per-thread arenas for reuse, and they never fit the next job exactly, so the
process's resident memory ratchets up with every result opened even though the objects alive do
not grow. Measured on a 4 M-point result opened and closed eight times: the resident memory grew
from 390 to 566 MB while the live allocations (tracemalloc) stayed at 61 MB, the two cached
results. With ``malloc_trim(0)`` after each close it stayed between 169 and 185 MB.

The trim itself is :func:`jointseg.memory.release_memory`; what is the viewer's own is the
timing: :func:`release_soon` asks for it a moment after a tab closes or a job is shown, once
viser has dropped what it was sending, and once for a burst of such calls.
"""

from __future__ import annotations

import logging
import threading
import time

from jointseg.memory import can_release, release_memory

log = logging.getLogger(__name__)

#: Seconds between a tab closing (or a job shown) and the trim: viser frees the tab's scene
#: and the sent messages on its event loop after the viewer's callback has returned.
TRIM_DELAY_S = 1.0

_lock = threading.Lock()
_due: float | None = None  # when the pending trim runs (time.monotonic), None when none is


def release_soon(delay_s: float = TRIM_DELAY_S) -> None:
    """:func:`jointseg.memory.release_memory` ``delay_s`` after the last of the calls that come
    close together, on one daemon thread."""
    global _due
    if not can_release():
        return
    with _lock:
        idle = _due is None
        _due = time.monotonic() + delay_s
    if idle:
        threading.Thread(target=_trim_when_due, name="malloc-trim", daemon=True).start()


def _trim_when_due() -> None:
    global _due
    while True:
        with _lock:
            assert _due is not None
            wait = _due - time.monotonic()
            if wait <= 0:
                _due = None
                break
        time.sleep(wait)
    try:
        release_memory()
    except Exception:  # a failed trim must not take anything else down
        log.exception("malloc_trim failed")
