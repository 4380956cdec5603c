"""The API's routers: ``/v1/jobs...`` (:mod:`.jobs`), the labels versions and reruns
(:mod:`.labels`) and ``/healthz`` (:mod:`.health`)."""

from __future__ import annotations

from server.api.routes.health import health_router
from server.api.routes.jobs import jobs_router
from server.api.routes.labels import labels_router

__all__ = ["health_router", "jobs_router", "labels_router"]
