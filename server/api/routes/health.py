"""``/healthz``: whether the database, the queue and the workers are alive (no API key)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from server.api.deps import ServicesDep
from server.api.errors import error_responses
from server.schemas import Health, WorkerView
from server.state import lifecycle
from server.state.db import ping

health_router = APIRouter(tags=["health"])


@health_router.get(
    "/healthz",
    response_model=Health,
    responses={503: {"model": Health}, **error_responses(405, 500)},
)
def healthz(services: ServicesDep) -> Any:
    """Database, queue and worker liveness (503 when the database or the queue is down)."""
    database = ping(services.engine)
    try:
        pending: int | None = services.queue.pending()
    except Exception:  # noqa: BLE001 - any failure means the queue is unreachable
        pending = None
    workers: list[WorkerView] = []
    if database:
        with services.sessions() as session:
            rows = lifecycle.live_workers(session, timeout_s=services.settings.heartbeat_timeout_s)
            workers = [WorkerView.model_validate(w, from_attributes=True) for w in rows]
    up = database and pending is not None
    health = Health(
        status="unavailable" if not up else ("ok" if workers else "degraded"),
        database=database,
        queue=pending is not None,
        queue_kind=services.queue.kind,
        pending=pending,
        workers=workers,
    )
    return JSONResponse(health.model_dump(mode="json"), status_code=200 if up else 503)
