"""The API's routers: ``/v1/jobs...`` (:mod:`.jobs`), the labels versions and reruns
(:mod:`.labels`), the models learnt from corrections (:mod:`.models`), ``/healthz``
(:mod:`.health`) and ``/metrics`` (:mod:`.metrics`)."""

from __future__ import annotations

from server.api.routes.health import health_router
from server.api.routes.jobs import jobs_router
from server.api.routes.labels import labels_router
from server.api.routes.metrics import metrics_router
from server.api.routes.models import models_router

__all__ = ["health_router", "jobs_router", "labels_router", "metrics_router", "models_router"]
