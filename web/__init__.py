"""jointseg viewer (viser scene and job page). Depends on `server` and `jointseg`."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def service_parts() -> tuple[list[Any], list[Callable[[Any], None]]]:
    """The job page router and the viewer process for ``jointseg serve`` (see web.serve)."""
    from web.serve import service_parts as parts

    return parts()
