"""One progress signature and one cancellation object for every stage.

Stages call ``progress(stage, fraction)`` with fraction in [0, 1]; the CLI turns the calls into
a progress bar and the job worker into the job row. Cancellation is any object with ``is_set()``
(a ``threading.Event`` works), checked inside long loops.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from jointseg.exceptions import Cancelled

ProgressFn = Callable[[str, float], None]


class CancelToken(Protocol):
    """Anything with ``is_set()``, e.g. ``threading.Event``."""

    def is_set(self) -> bool: ...


def report(progress: ProgressFn | None, stage: str, fraction: float) -> None:
    """Call ``progress`` when given, clamping ``fraction`` to [0, 1]."""
    if progress is not None:
        progress(stage, min(1.0, max(0.0, float(fraction))))


def check_cancel(cancel: CancelToken | None) -> None:
    """Raise :class:`Cancelled` when ``cancel`` is set."""
    if cancel is not None and cancel.is_set():
        raise Cancelled("cancelled by request")
