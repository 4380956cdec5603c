"""``/v1/jobs...``: thin wrappers that parse, call :mod:`server.state.jobs` and friends, and answer
:mod:`server.schemas` models.

Every route depends on :func:`server.api.auth.require_api_key`, whose tenant limits what it sees:
a key's own jobs, or every job for admin keys and an open service (another key's job is 404, as a
job that does not exist). Errors are raised as jointseg's domain errors and turned into status
codes by the app's one exception handler (:mod:`server.api.errors`).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse

from jointseg.objects.records import LayoutReport
from server.api.auth import Tenant, TenantDep, require_api_key
from server.api.deps import Services, ServicesDep, SessionDep
from server.api.errors import ERROR_RESPONSES, error_responses
from server.api.submissions import submit
from server.api.uploads import UPLOAD_OPENAPI, receive_upload
from server.corrections import resolve_version, version_file
from server.messages import public_report_bytes
from server.results import content_disposition, download_name, layout_from
from server.schemas import FINAL_STATUSES, JobList, JobResponse, JobStatus, JobView
from server.state import jobs
from server.storage import ResultFormat

JobId = Annotated[
    str,
    Path(
        pattern=r"^[0-9a-f]{32}$",
        description="Job id: 32 hex digits. Another API key's job answers 404, as an unknown id "
        "does (admin keys see every job).",
    ),
]

Version = Annotated[
    int | None,
    Query(
        ge=0,
        le=1 << 30,
        description="Labels version: 0 is the run's own labels, 1, 2, ... the corrections "
        "(`PATCH .../labels`); default the current one. A version the job lacks is 404.",
    ),
]

#: The IFC download's media type (STEP physical file, ISO 10303-21).
IFC_MEDIA_TYPE = "application/x-step"

jobs_router = APIRouter(
    prefix="/v1", tags=["jobs"], dependencies=[Depends(require_api_key)], responses=ERROR_RESPONSES
)


@jobs_router.post(
    "/jobs",
    status_code=201,
    response_model=JobResponse,
    openapi_extra=UPLOAD_OPENAPI,
    responses=error_responses(413, 415, 503),
)
async def create_job(
    request: Request, services: ServicesDep, response: Response, tenant: TenantDep
) -> JobResponse:
    """Upload a scan (form field ``file``) with an optional ``config`` (PipelineConfig JSON).

    The upload streams to disk; it is checked (header, point count, and every point of files
    up to ``full_check_max_bytes``) before the job is queued. The job belongs to the API key
    that submitted it: only that key (and admin keys) can see, download, cancel or delete it.
    """
    upload = await receive_upload(
        request, services.storage, max_bytes=services.settings.max_upload_bytes
    )
    view = await run_in_threadpool(
        lambda: submit(services, upload, tenant.owner, owned_by=tenant.scope)
    )
    response.headers["Location"] = f"/v1/jobs/{view.id}"
    return JobResponse.from_view(view)


@jobs_router.get("/jobs", response_model=JobList)
def list_jobs(
    session: SessionDep,
    tenant: TenantDep,
    status: Annotated[JobStatus | None, Query(description="Only this status.")] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=1 << 40)] = 0,
) -> JobList:
    """Jobs, newest first, a page at a time: the calling key's own (every job for admin keys
    and on a service without keys)."""
    scope = tenant.scope
    items = jobs.list_jobs(session, status=status, limit=limit, offset=offset, owned_by=scope)
    total = jobs.count_jobs(session, status=status, owned_by=scope)
    return JobList(
        items=[JobResponse.from_view(v) for v in items], total=total, limit=limit, offset=offset
    )


@jobs_router.get("/jobs/{job_id}", response_model=JobResponse)
def get_job(job_id: JobId, session: SessionDep, tenant: TenantDep) -> JobResponse:
    """Status, stage, progress, timings, points and error of one job."""
    return JobResponse.from_view(jobs.get_job(session, job_id, owned_by=tenant.scope))


@jobs_router.get(
    "/jobs/{job_id}/result",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The scan (ply, las, laz) or its IFC4 model (ifc).",
            "content": {"application/octet-stream": {}, IFC_MEDIA_TYPE: {}},
        },
        **error_responses(409),
    },
)
async def get_result(
    job_id: JobId,
    services: ServicesDep,
    tenant: TenantDep,
    format: Annotated[
        ResultFormat, Query(description="ply, las or laz (the scan), or ifc (an IFC4 model).")
    ] = "ply",
    version: Version = None,
) -> FileResponse:
    """The segmented scan with every field of ``jointseg segment``, or its IFC4 model of rooms,
    walls, doors, windows and furniture (409 until it succeeded, or when the run found no
    objects or rooms). A corrected labels version's scan has ``fused_label`` corrected and a
    ``user_label`` field (LAS: classification 64 + the class where corrected)."""
    view, number = await run_in_threadpool(_version, services, job_id, tenant, version)
    path = await run_in_threadpool(version_file, services.storage, job_id, number, format)
    media = IFC_MEDIA_TYPE if format == "ifc" else "application/octet-stream"
    name = download_name(view.filename, format, number)
    return FileResponse(path, media_type=media, filename=name)


@jobs_router.get(
    "/jobs/{job_id}/objects", response_model=LayoutReport, responses=error_responses(409)
)
async def get_objects(
    job_id: JobId,
    services: ServicesDep,
    tenant: TenantDep,
    response: Response,
    version: Version = None,
) -> LayoutReport:
    """The objects, rooms and walls (with their doors and windows) the run found, as
    ``jointseg segment --objects`` writes them (409 until it succeeded, or without them); of
    a corrected labels version, found from its labels."""
    view, number = await run_in_threadpool(_version, services, job_id, tenant, version)
    report = await run_in_threadpool(version_file, services.storage, job_id, number, "report")
    layout = await run_in_threadpool(layout_from, report)
    name = download_name(view.filename, "objects", number)
    response.headers["Content-Disposition"] = content_disposition(name, "inline")
    return layout


@jobs_router.get(
    "/jobs/{job_id}/report",
    responses={200: {"content": {"application/json": {}}}, **error_responses(409)},
)
async def get_report(
    job_id: JobId, services: ServicesDep, tenant: TenantDep, version: Version = None
) -> Response:
    """The job's report.json (as ``jointseg segment --report`` writes it), with paths on the
    server reduced to file names (:func:`server.messages.public_report`); a corrected labels
    version's has a ``labels`` section and that version's objects and rooms."""
    view, number = await run_in_threadpool(_version, services, job_id, tenant, version)
    path = await run_in_threadpool(version_file, services.storage, job_id, number, "report")
    body = await run_in_threadpool(public_report_bytes, path)
    name = download_name(view.filename, "report", number)
    headers = {"Content-Disposition": content_disposition(name, "inline")}
    return Response(body, media_type="application/json", headers=headers)


def _version(
    services: Services, job_id: str, tenant: Tenant, version: int | None
) -> tuple[JobView, int]:
    """The succeeded job as ``tenant`` may see it and the labels version asked for (the async
    routes run this in a thread; 409 before it succeeded, 404 for a version it lacks)."""
    return resolve_version(services.sessions, job_id, version, owned_by=tenant.scope)


@jobs_router.delete(
    "/jobs/{job_id}",
    status_code=202,
    response_model=JobResponse,
    responses={
        204: {"description": "The finished job and its files were deleted."},
        **error_responses(409),
    },
)
def delete_job(job_id: JobId, services: ServicesDep, session: SessionDep, tenant: TenantDep) -> Any:
    """Cancel a queued or running job (202); delete a finished job and its files (204)."""
    scope = tenant.scope
    view = jobs.get_job(session, job_id, owned_by=scope)
    if view.status not in FINAL_STATUSES:
        view = jobs.cancel_job(session, job_id, owned_by=scope)
        if view.finished:  # a queued job, or a tiled one with no tile running: its folder goes
            services.storage.remove_tiles(job_id)
        return JobResponse.from_view(view)
    jobs.delete_job_row(session, job_id, owned_by=scope)
    services.storage.delete(job_id)
    return Response(status_code=204)
