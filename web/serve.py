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
from types import FrameType

from jointseg.io.atomic import atomic_open
from server.api.auth import key_accepted
from server.serve_parts import ServeParts
from server.settings import Settings
from web.page import VIEWER_FILE, job_page_router

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
    authorise = None if not settings.api_keys else (lambda key: key_accepted(settings, key))
    viewer = Viewer(
        source, host=settings.viewer_host, port=settings.viewer_port, authorise=authorise
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


def service_parts() -> ServeParts:
    """The ``jointseg.serve_parts`` entry point: the job page router and the viewer process."""
    return ServeParts(routers=[job_page_router()], processes=[run_viewer])
