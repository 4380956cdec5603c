"""What other packages add to ``jointseg serve``, found through the entry-point group
:data:`SERVE_PARTS_GROUP`, so that ``server`` never imports the layers built on it.

An entry point names a callable returning :class:`ServeParts`: routers to mount on the API
(they can depend on :func:`server.api.auth.require_api_key` and :mod:`server.api.deps`)
and processes to run beside it. ``web`` registers its job page and viewer this way (see
pyproject.toml); without it the service runs the API and the workers only.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import NamedTuple

from fastapi import APIRouter

from server.settings import Settings

log = logging.getLogger(__name__)

#: Entry-point group of ``jointseg serve``'s extra parts; each entry point is a callable
#: ``() -> ServeParts``.
SERVE_PARTS_GROUP = "jointseg.serve_parts"

#: A process run beside the API as ``target(settings)``: a module-level function (it is
#: started with ``spawn``) that exits on SIGTERM.
ExtraProcess = Callable[[Settings], None]


class ServeParts(NamedTuple):
    """Routers to mount on the API and processes to run beside it."""

    routers: list[APIRouter]
    processes: list[ExtraProcess]


def load_serve_parts(group: str = SERVE_PARTS_GROUP) -> ServeParts:
    """Every installed part of ``jointseg serve``; a broken one is skipped with a warning."""
    routers: list[APIRouter] = []
    processes: list[ExtraProcess] = []
    found = entry_points(group=group)
    for ep in found:
        try:
            parts = ep.load()()
        except Exception as exc:  # noqa: BLE001 - a broken extra must not stop the API
            log.warning("jointseg serve: skipping %r (%s): %s", ep.name, ep.value, exc)
            continue
        routers.extend(parts.routers)
        processes.extend(parts.processes)
        log.info(
            "jointseg serve: %s adds %d routers and %d processes",
            ep.name,
            len(parts.routers),
            len(parts.processes),
        )
    if not found:
        log.warning(
            "jointseg serve: no viewer or job page installed (entry-point group %r is empty); "
            "serving the API and the workers only",
            group,
        )
    return ServeParts(routers, processes)
