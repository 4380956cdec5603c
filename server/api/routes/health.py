"""``/healthz``: whether the service is up, for anyone; its parts, for accepted keys.

Why: load balancers and uptime checks call it without a key, so it must answer them, but it
named the host, the workers' process ids and the jobs they run to anyone. Without an accepted
key a locked service now says only ``status`` (and 200 or 503). An accepted key also gets the
database, the queue and the live workers, with the job ids of its own jobs only (admin keys:
all); on an open service (no keys) every caller gets that full answer, as every route is open.
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends
from fastapi.responses import JSONResponse
from fastapi.security import HTTPAuthorizationCredentials
from sqlalchemy import select
from sqlalchemy.orm import Session

from server.api.auth import Tenant, bearer, tenant_for
from server.api.deps import ServicesDep
from server.api.errors import error_responses
from server.schemas import Health, WorkerView
from server.state import lifecycle
from server.state.db import ping
from server.state.models import Job

health_router = APIRouter(tags=["health"])


def _caller(
    services: ServicesDep,
    credentials: HTTPAuthorizationCredentials | None = Depends(bearer),  # noqa: B008
) -> Tenant | None:
    """The caller's tenant, or None without an accepted key (never a 401 here)."""
    key = credentials.credentials if credentials is not None else None
    if credentials is not None and credentials.scheme.lower() != "bearer":
        key = None
    return tenant_for(services.settings, key)


@health_router.get(
    "/healthz",
    response_model=Health,
    responses={503: {"model": Health}, **error_responses(405, 500)},
)
def healthz(services: ServicesDep, caller: Annotated[Tenant | None, Depends(_caller)]) -> Any:
    """Whether the service is up (503 when the database or the queue is down); with an
    accepted key, or on an open service, also the database, queue and worker details."""
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
            if caller is not None and caller.scope is not None:
                workers = _own_jobs_only(session, workers, caller.scope)
    up = database and pending is not None
    status = "unavailable" if not up else ("ok" if workers else "degraded")
    if caller is None:
        health = Health(status=status)
    else:
        health = Health(
            status=status,
            database=database,
            queue=pending is not None,
            queue_kind=services.queue.kind,
            pending=pending,
            workers=workers,
        )
    body = health.model_dump(mode="json", exclude_unset=True)
    return JSONResponse(body, status_code=200 if up else 503)


def _own_jobs_only(session: Session, workers: list[WorkerView], owner: str) -> list[WorkerView]:
    """The workers with the ids of other owners' jobs blanked (tenants, see auth)."""
    busy = {w.job_id for w in workers if w.job_id}
    if not busy:
        return workers
    own = set(session.scalars(select(Job.id).where(Job.id.in_(busy), Job.owner == owner)))
    return [w if w.job_id in own else w.model_copy(update={"job_id": None}) for w in workers]
