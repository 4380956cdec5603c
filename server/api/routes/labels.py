"""``/v1/jobs/{id}/labels`` and ``/v1/jobs/{id}/rerun``: thin routes over
:mod:`server.corrections` (versioned corrections of a job's labels) and
:func:`server.api.submissions.rerun` (the same upload again with another frame).

The labels' ``ETag`` names their version (``"v3"``); a correction sends it back as
``If-Match`` (428 without, 412 when another correction came first), so two users never
overwrite each other's work unseen.
"""

from __future__ import annotations

import json
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Header, Request, Response
from fastapi.concurrency import run_in_threadpool

from jointseg.exceptions import ConfigError, UploadTooLarge
from jointseg.labels.edits import MAX_IDS, EditList, parse_edits
from server.api.auth import TenantDep, require_api_key
from server.api.deps import ServicesDep
from server.api.errors import ERROR_RESPONSES, error_responses
from server.api.routes.jobs import JobId
from server.api.submissions import rerun
from server.corrections import correct, labels_state, require_if_match, succeeded_job
from server.schemas import JobResponse, LabelsState, RerunRequest
from server.settings import Settings

labels_router = APIRouter(
    prefix="/v1",
    tags=["labels"],
    dependencies=[Depends(require_api_key)],
    responses=ERROR_RESPONSES,
)

#: The labels' ``ETag`` header, as OpenAPI lists it.
ETAG_HEADER = {
    "ETag": {
        "description": 'The labels version, e.g. `"v3"`: send it as `If-Match` to correct them.',
        "schema": {"type": "string"},
    }
}


def _inlined(schema: Any, defs: dict[str, Any]) -> Any:
    """``schema`` with its ``$defs`` references replaced by the definitions (OpenAPI resolves
    a ``$ref`` against the whole document, not the schema)."""
    if isinstance(schema, dict):
        ref = schema.get("$ref")
        if isinstance(ref, str) and ref.startswith("#/$defs/"):
            return _inlined(defs[ref.rsplit("/", 1)[1]], defs)
        return {k: _inlined(v, defs) for k, v in schema.items() if k != "$defs"}
    if isinstance(schema, list):
        return [_inlined(item, defs) for item in schema]
    return schema


_EDITS_SCHEMA = EditList.model_json_schema()
#: The PATCH body as OpenAPI describes it (the route reads the stream itself, within limits).
EDITS_OPENAPI = {
    "requestBody": {
        "required": True,
        "content": {
            "application/json": {"schema": _inlined(_EDITS_SCHEMA, _EDITS_SCHEMA.get("$defs", {}))}
        },
    }
}


@labels_router.get(
    "/jobs/{job_id}/labels",
    response_model=LabelsState,
    responses={200: {"headers": ETAG_HEADER}, **error_responses(409)},
)
def get_labels(
    job_id: JobId, services: ServicesDep, tenant: TenantDep, response: Response
) -> LabelsState:
    """The job's current labels version and its history (version 0: the run's own labels);
    the ``ETag`` header names the current version."""
    state = labels_state(services.sessions, services.storage, job_id, owned_by=tenant.scope)
    response.headers["ETag"] = state.etag
    return state


async def _read_body(request: Request, max_bytes: int) -> bytes:
    """The request body, refused (413) past ``max_bytes`` before or while it streams."""
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > max_bytes:
        raise UploadTooLarge(f"request body is larger than the limit of {max_bytes:,} bytes")
    chunks: list[bytes] = []
    size = 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > max_bytes:
            raise UploadTooLarge(f"request body is larger than the limit of {max_bytes:,} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


def parse_edit_body(raw: bytes, settings: Settings) -> EditList:
    """A PATCH body as an edit list within the service's limits.

    Raises
    ------
    ConfigError
        For a body that is not JSON, or an edit list that is malformed, names an unknown class,
        or names more ids than ``settings.max_points``; the message names the field.
    """
    try:
        body = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"body: not valid JSON ({exc})") from None
    return parse_edits(body, max_ids=min(MAX_IDS, settings.max_points))


@labels_router.patch(
    "/jobs/{job_id}/labels",
    response_model=LabelsState,
    openapi_extra=EDITS_OPENAPI,
    responses={200: {"headers": ETAG_HEADER}, **error_responses(409, 412, 413, 428)},
)
async def patch_labels(
    job_id: JobId,
    request: Request,
    services: ServicesDep,
    tenant: TenantDep,
    response: Response,
    if_match: Annotated[
        str | None, Header(description='The current labels\' ETag (`"v3"`); required.')
    ] = None,
) -> LabelsState:
    """Correct the labels by segment, point or box (``{"edits": [...]}``; a later edit wins
    where two cover a point): a new labels version, whose ``ETag`` the answer carries.
    Nothing is written when anything is refused."""
    await run_in_threadpool(succeeded_job, services.sessions, job_id, owned_by=tenant.scope)
    require_if_match(job_id, if_match)  # before the body is read
    raw = await _read_body(request, services.settings.max_upload_bytes)
    edits = await run_in_threadpool(parse_edit_body, raw, services.settings)
    state = await run_in_threadpool(
        lambda: correct(
            services.sessions,
            services.storage,
            job_id,
            edits,
            if_match=if_match,
            owner=tenant.owner,
            owned_by=tenant.scope,
        )
    )
    response.headers["ETag"] = state.etag
    return state


@labels_router.post(
    "/jobs/{job_id}/rerun",
    status_code=201,
    response_model=JobResponse,
    responses=error_responses(503),
)
async def rerun_job(
    job_id: JobId, body: RerunRequest, services: ServicesDep, tenant: TenantDep, response: Response
) -> JobResponse:
    """A new job from the same upload with the job's config and these frame settings over its
    own (its ``rerun_of`` names this job); the job and its labels versions stay as they are."""
    frame = body.frame.model_dump(exclude_unset=True)
    view = await run_in_threadpool(
        lambda: rerun(services, job_id, frame, owner=tenant.owner, owned_by=tenant.scope)
    )
    response.headers["Location"] = f"/v1/jobs/{view.id}"
    return JobResponse.from_view(view)
