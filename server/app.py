"""The FastAPI application: services wired at start-up, one exception handler, the routes.

``create_app`` is what uvicorn serves; the viewer adds its own routers to the app it returns
(through :func:`server.service.run_service`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse
from sqlalchemy import Engine

from jointseg.exceptions import (
    AuthenticationError,
    ConfigError,
    JobNotFound,
    JobStateError,
    JointsegError,
    QueueUnavailable,
    ScanFormatError,
    UnsupportedFormatError,
    UploadTooLarge,
)
from server.db import SessionFactory, init_db, make_engine, make_sessions
from server.queue import JobQueue
from server.settings import Settings
from server.storage import Storage

log = logging.getLogger(__name__)

#: HTTP status of each domain error; the most specific class listed first wins.
ERROR_STATUS: tuple[tuple[type[JointsegError], int], ...] = (
    (AuthenticationError, 401),
    (JobNotFound, 404),
    (JobStateError, 409),
    (UploadTooLarge, 413),
    (UnsupportedFormatError, 415),
    (ScanFormatError, 422),
    (ConfigError, 422),
    (QueueUnavailable, 503),
)


@dataclass
class Services:
    """What the routes need, built once per app from its settings."""

    settings: Settings
    engine: Engine
    sessions: SessionFactory
    storage: Storage
    queue: JobQueue


def status_for(exc: JointsegError) -> int:
    """The HTTP status of a domain error (400 for one not listed)."""
    for cls, status in ERROR_STATUS:
        if isinstance(exc, cls):
            return status
    return 400


async def domain_error(request: Request, exc: Exception) -> JSONResponse:
    """The one handler mapping jointseg's errors to a status and ``{"detail", "error"}``."""
    assert isinstance(exc, JointsegError)
    status = status_for(exc)
    headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
    if status >= 500:
        log.error("%s %s: %s", request.method, request.url.path, exc)
    return JSONResponse(
        {"detail": str(exc), "error": type(exc).__name__}, status_code=status, headers=headers
    )


def _reaper(services: Services, stop: threading.Event) -> None:
    """Recover jobs of lost workers even when every worker is gone (see lifecycle.reap_stale)."""
    from server.worker import reap_and_requeue

    while not stop.wait(services.settings.heartbeat_interval_s):
        try:
            reap_and_requeue(services.sessions, services.queue, services.settings)
        except Exception:  # noqa: BLE001 - retried at the next interval
            log.warning("reaper failed", exc_info=True)


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the API for ``settings`` (default: from the environment and JOINTSEG_CONFIG)."""
    from server.routes import health_router, jobs_router

    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        engine = make_engine(settings)
        init_db(engine)
        storage = Storage(settings.data_dir)
        storage.clean_incoming()
        services = Services(settings, engine, make_sessions(engine), storage, JobQueue(settings))
        app.state.services = services
        stop = threading.Event()
        reaper = threading.Thread(
            target=_reaper, args=(services, stop), name="jointseg-reaper", daemon=True
        )
        reaper.start()
        log.info(
            "API ready: data in %s, %s queue, %s",
            settings.data_dir,
            settings.queue,
            "API keys required" if settings.api_keys else "no API keys",
        )
        try:
            yield
        finally:
            stop.set()
            reaper.join(timeout=5)
            services.queue.close()
            engine.dispose()

    app = FastAPI(
        title="jointseg job service",
        version="1",
        summary="Upload indoor scans, poll their segmentation jobs, download the results.",
        lifespan=lifespan,
    )
    app.add_exception_handler(JointsegError, domain_error)
    app.include_router(jobs_router)
    app.include_router(health_router)
    return app
