"""The FastAPI application: services wired at start-up, one exception handler, the routes.

``create_app`` is what uvicorn serves; ``jointseg serve`` adds the routers of its installed
parts (the job page, see :mod:`server.serve_parts`) to the app it returns.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI

from server.api.checks import UploadChecker
from server.api.deps import Services
from server.api.errors import install_error_handlers
from server.api.routes import (
    health_router,
    jobs_router,
    labels_router,
    metrics_router,
    models_router,
)
from server.queue import JobQueue
from server.settings import Settings
from server.state.db import init_db, make_engine, make_sessions
from server.state.reaper import ReaperThread
from server.storage import Storage

log = logging.getLogger(__name__)

#: The schema's description: keys and tenants (docs/guide/job-service.md#api-keys).
DESCRIPTION = (
    "With API keys configured, every `/v1` route needs `Authorization: Bearer <key>` (401 "
    "otherwise). Each key is a tenant: it lists, reads, downloads, cancels and deletes only "
    "the jobs it submitted; another key's job answers 404 exactly as a job that does not "
    "exist. Admin keys see every job. Without keys the service is open and everyone sees "
    "every job."
)


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the API for ``settings`` (default: from the environment and JOINTSEG_CONFIG)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        engine = make_engine(settings)
        init_db(engine)
        storage = Storage(settings.data_dir)
        storage.claim_incoming()  # and removes the partial uploads of ended API processes
        storage.clean_incoming()
        checker = UploadChecker(settings)
        services = Services(
            settings, engine, make_sessions(engine), storage, JobQueue(settings), checker
        )
        app.state.services = services
        checker.warm()
        # recovers jobs of lost workers even when every worker is gone
        reaper = ReaperThread(services.sessions, services.queue, settings)
        reaper.start()
        log.info(
            "API ready: data in %s, %s queue, %s",
            settings.data_dir,
            settings.queue,
            "API keys required" if settings.keys_required else "no API keys",
        )
        try:
            yield
        finally:
            reaper.stop()
            checker.close()
            services.queue.close()
            engine.dispose()
            storage.release_incoming()

    app = FastAPI(
        title="jointseg job service",
        version="1",
        summary="Upload indoor scans, poll their segmentation jobs, download the results.",
        description=DESCRIPTION,
        lifespan=lifespan,
    )
    install_error_handlers(app)
    app.include_router(jobs_router)
    app.include_router(labels_router)
    app.include_router(models_router)
    app.include_router(health_router)
    app.include_router(metrics_router)
    return app
