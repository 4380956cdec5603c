"""The viewer's part of ``jointseg serve``: the job page router and the viewer process.

``server.cli.serve`` asks :func:`web.service_parts` for them and hands them to
:func:`server.service.run_service`, which mounts the router on the API and runs
:func:`run_viewer` in its own spawned process.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

from fastapi import APIRouter

from jointseg.io.atomic import atomic_open
from server.settings import Settings
from web.page import VIEWER_FILE, job_page_router

log = logging.getLogger(__name__)


def run_viewer(settings: Settings) -> None:
    """Serve the viewer on ``settings.viewer_host:viewer_port`` until SIGTERM or SIGINT.

    The port actually used (viser moves to the next free one when the configured port is
    taken) is recorded in ``data_dir/viewer.json`` for the job page's links.
    """
    from web.service_source import ServiceSource
    from web.viewer import Viewer

    stop = threading.Event()

    def note(_signum: int, _frame: FrameType | None) -> None:
        stop.set()

    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, note)
    source = ServiceSource(settings)
    viewer = Viewer(source, host=settings.viewer_host, port=settings.viewer_port)
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


def service_parts() -> tuple[list[APIRouter], list[Callable[[Any], None]]]:
    """The routers to mount on the API and the processes to run beside it."""
    return [job_page_router()], [run_viewer]
