"""The viewer's part of ``jointseg serve``: the job page router and the viewer process.

:func:`service_parts` is registered in the entry-point group ``jointseg.serve_parts``
(pyproject.toml); ``jointseg serve`` loads it through :func:`server.serve_parts.load_serve_parts`
and hands the parts to :func:`server.service.run_service`, which mounts the router on the API
and runs :func:`run_viewer` in its own spawned process. server never imports web.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import TYPE_CHECKING

from jointseg.exceptions import AuthenticationError
from jointseg.io.atomic import atomic_open
from server.api.auth import key_accepted, tenant_for
from server.serve_parts import ServeParts
from server.settings import Settings
from web.page import VIEWER_FILE, job_page_router

if TYPE_CHECKING:  # viser loads only in the viewer's own process
    from web.service_source import ServiceSource
    from web.sources import JobSource

log = logging.getLogger(__name__)


def run_viewer(settings: Settings) -> None:
    """Serve the viewer on ``settings.viewer_host:viewer_port`` until SIGTERM or SIGINT.

    The port actually used (viser moves to the next free one when the configured port is
    taken) is recorded in ``data_dir/viewer.json`` for the job page's links.
    """
    # deferred: viser (and the scene code) load only in the viewer's own process, not in the
    # API process that imports this module for the job page router
    from web.service_source import ServiceSource
    from web.viewer import Viewer

    stop = threading.Event()

    def note(_signum: int, _frame: FrameType | None) -> None:
        stop.set()

    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, note)
    source = ServiceSource(settings)
    authorise = None if not settings.keys_required else (lambda key: key_accepted(settings, key))
    viewer = Viewer(
        source,
        host=settings.viewer_host,
        port=settings.viewer_port,
        authorise=authorise,
        scope=tenant_scope(settings, source),
    )
    if viewer.port != settings.viewer_port:
        log.warning("viewer port %d is taken; using %d", settings.viewer_port, viewer.port)
    record = settings.data_dir / VIEWER_FILE
    with atomic_open(record) as fh:
        fh.write(json.dumps({"port": viewer.port, "pid": os.getpid()}).encode())
    log.info("viewer on http://%s:%d", settings.viewer_host, viewer.port)
    try:
        stop.wait()
    finally:
        viewer.stop()
        source.close()
        log.info("viewer stopped")


def tenant_scope(settings: Settings, source: ServiceSource) -> Callable[[str | None], JobSource]:
    """What a viewer client signed in with a key sees: the same jobs as that key through the
    API (its own; every job for admin keys and on an open service)."""

    def scope(key: str | None) -> JobSource:
        tenant = tenant_for(settings, key)
        if tenant is None:  # the viewer asks only for accepted keys; refuse rather than widen
            raise AuthenticationError("invalid API key")
        return source.for_tenant(tenant)

    return scope


def service_parts() -> ServeParts:
    """The ``jointseg.serve_parts`` entry point: the job page router and the viewer process."""
    return ServeParts(routers=[job_page_router()], processes=[run_viewer])
