"""``GET /metrics``: the service's series in Prometheus' text format (:mod:`server.metrics`).

Guarded like the rest of the API, and more: when keys are set only an admin key may read it
(the counts cover every tenant's jobs), an ordinary key gets 403 and no key 401."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response

from jointseg.exceptions import Forbidden
from server.api.auth import TenantDep
from server.api.deps import ServicesDep
from server.api.errors import error_responses
from server.metrics import page
from server.state.metric_counts import metric_counts

metrics_router = APIRouter(tags=["health"])


@metrics_router.get(
    "/metrics",
    response_class=Response,
    responses={
        200: {"content": {"text/plain": {}}, "description": "Prometheus text format"},
        **error_responses(401, 403, 405, 500),
    },
)
async def metrics(services: ServicesDep, caller: TenantDep) -> Any:
    """Jobs by status, queue depth, live workers (from the job table), job and stage
    durations, failures by error and upload bytes (counted by the API and the workers)."""
    if services.settings.keys_required and not caller.admin:
        raise Forbidden("/metrics needs an admin key (admin_keys): the counts cover every tenant")

    def read() -> dict[str, Any]:
        with services.sessions() as session:
            return metric_counts(session, timeout_s=services.settings.heartbeat_timeout_s)

    body, content_type = await run_in_threadpool(page, read)
    return Response(content=body, media_type=content_type)
