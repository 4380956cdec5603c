"""What the viewer's browser tests share: a free loopback port, and the server-side view of
the tab that shows a job. A module of its own (not conftest) so tests import it by name."""

from __future__ import annotations

import socket
import time
from typing import Any


def free_port() -> int:
    """A loopback port nobody listens on now."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def view_of(viewer: Any, job_id: str, exclude: tuple[Any, ...] = ()) -> Any:
    """The server-side view of a tab showing ``job_id`` (other than those in ``exclude``),
    waiting up to 15 s for it."""
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        found = [v for v in list(viewer.views.values()) if v.job_id == job_id and v not in exclude]
        if found:
            return found[0]
        time.sleep(0.1)
    raise AssertionError(f"no client shows {job_id}")
