"""``/v1/models...``: models learnt from an owner's corrected jobs (issue 66), thin routes over
:mod:`server.api.model_requests` and :mod:`server.state.model_jobs`.

A model is a job of the queue (same workers, progress, cancel, requeue of a dead worker's) whose
result is a RandLA-Net checkpoint; a later job uses it with ``network.weights: "model:<id>"``.
Tenants as for jobs: another key's model answers 404, as an unknown id.
"""

from __future__ import annotations

import re
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Query, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse

from jointseg.exceptions import JobStateError
from server.api.auth import TenantDep, require_api_key
from server.api.deps import ServicesDep, SessionDep
from server.api.errors import ERROR_RESPONSES, error_responses
from server.api.model_requests import submit_model
from server.schemas import JobStatus, ModelList, ModelRequest, ModelResponse
from server.state import model_jobs

ModelId = Annotated[
    str,
    Path(
        pattern=r"^[0-9a-f]{32}$",
        description="Model id: 32 hex digits. Another API key's model answers 404, as an "
        "unknown id does (admin keys see every model).",
    ),
]

models_router = APIRouter(
    prefix="/v1",
    tags=["models"],
    dependencies=[Depends(require_api_key)],
    responses=ERROR_RESPONSES,
)


@models_router.post(
    "/models", status_code=201, response_model=ModelResponse, responses=error_responses(409, 503)
)
async def create_model(
    body: ModelRequest, services: ServicesDep, tenant: TenantDep, response: Response
) -> ModelResponse:
    """Learn a model from the caller's corrected jobs (each at its current labels version):
    queued and run by the workers like a job. 404 names an unknown (or another key's) job,
    409 one that has not succeeded, 422 one without corrected points; nothing is created then.
    """
    view = await run_in_threadpool(
        lambda: submit_model(services, body, owner=tenant.owner, owned_by=tenant.scope)
    )
    response.headers["Location"] = f"/v1/models/{view.id}"
    return ModelResponse.from_view(view)


@models_router.get("/models", response_model=ModelList)
def list_models(
    session: SessionDep,
    tenant: TenantDep,
    status: Annotated[JobStatus | None, Query(description="Only this status.")] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=1 << 40)] = 0,
) -> ModelList:
    """Models, newest first, a page at a time: the calling key's own (every model for admin
    keys and on a service without keys)."""
    items, total = model_jobs.list_models(
        session, status=status, limit=limit, offset=offset, owned_by=tenant.scope
    )
    return ModelList(
        items=[ModelResponse.from_view(v) for v in items], total=total, limit=limit, offset=offset
    )


@models_router.get("/models/{model_id}", response_model=ModelResponse)
def get_model(model_id: ModelId, session: SessionDep, tenant: TenantDep) -> ModelResponse:
    """Status, stage, progress and error of one model; once it succeeded, its card's
    ``adapted`` summary (scans and versions, corrected points, seconds)."""
    return ModelResponse.from_view(model_jobs.get_model(session, model_id, owned_by=tenant.scope))


def _file_name(name: str | None, model_id: str) -> str:
    """The download's name: the model's name made safe, else ``model-<id>``; ``.pt``."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", name or "").strip("._")[:80]
    return f"{stem or f'model-{model_id[:8]}'}.pt"


@models_router.get(
    "/models/{model_id}/file",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The model's checkpoint (.pt).",
            "content": {"application/octet-stream": {}},
        },
        **error_responses(409),
    },
)
def get_model_file(
    model_id: ModelId, services: ServicesDep, session: SessionDep, tenant: TenantDep
) -> FileResponse:
    """The model's RandLA-Net checkpoint, for ``jointseg segment --weights`` (409 until it
    succeeded)."""
    view = model_jobs.get_model(session, model_id, owned_by=tenant.scope)
    path = services.storage.model_path(model_id)
    if view.status != "succeeded" or not path.is_file():
        raise JobStateError(f"model {model_id} is {view.status}; no file yet")
    name = _file_name(view.name, model_id)
    return FileResponse(path, media_type="application/octet-stream", filename=name)


@models_router.delete(
    "/models/{model_id}",
    status_code=202,
    response_model=ModelResponse,
    responses={
        204: {"description": "The finished model and its file were deleted."},
        **error_responses(409),
    },
)
def delete_model(
    model_id: ModelId, services: ServicesDep, session: SessionDep, tenant: TenantDep
) -> Any:
    """Cancel a queued or learning model (202); delete a finished one and its file (204).
    Jobs that name it afterwards are refused (queued ones fail)."""
    scope = tenant.scope
    view = model_jobs.get_model(session, model_id, owned_by=scope)
    if not view.finished:
        return ModelResponse.from_view(model_jobs.cancel_model(session, model_id, owned_by=scope))
    model_jobs.delete_model_row(session, model_id, owned_by=scope)
    services.storage.delete(model_id)
    return Response(status_code=204)
