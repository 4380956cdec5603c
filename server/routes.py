"""HTTP routes: thin wrappers that parse, call :mod:`server.jobs` and friends, and answer models.

Every /v1 route depends on :func:`server.auth.require_api_key`; errors are raised as jointseg's
domain errors and turned into status codes by the app's one exception handler.
"""

from __future__ import annotations

from collections.abc import Iterator
from datetime import datetime
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse
from pydantic import BaseModel, Field
from sqlalchemy.orm import Session

from jointseg.exceptions import JobStateError
from server import jobs, lifecycle
from server.app import Services
from server.auth import require_api_key
from server.db import ping
from server.models import FINAL_STATUSES
from server.results import result_file
from server.storage import ResultFormat
from server.submissions import submit
from server.uploads import UPLOAD_OPENAPI, receive_upload

JobId = Annotated[str, Path(pattern=r"^[0-9a-f]{32}$", description="Job id: 32 hex digits.")]


def get_services(request: Request) -> Services:
    """The app's services (built by its lifespan)."""
    services: Services = request.app.state.services
    return services


def get_session(services: Annotated[Services, Depends(get_services)]) -> Iterator[Session]:
    """One database session per request."""
    with services.sessions() as session:
        yield session


ServicesDep = Annotated[Services, Depends(get_services)]
SessionDep = Annotated[Session, Depends(get_session)]


class JobLinks(BaseModel):
    """Where to find a job and its outputs."""

    self: str
    result: str
    report: str


class JobResponse(jobs.JobView):
    """A job with links to itself, its result and its report."""

    links: JobLinks


class JobList(BaseModel):
    """One page of jobs, newest first."""

    items: list[JobResponse]
    total: int = Field(description="Jobs matching the filter, on every page.")
    limit: int
    offset: int


class ErrorBody(BaseModel):
    """Every error's body."""

    detail: str
    error: str = Field(description="Error class, e.g. ScanFormatError.")


class WorkerView(BaseModel):
    """A worker process seen recently."""

    id: str
    hostname: str
    pid: int
    started_at: datetime
    seen_at: datetime
    job_id: str | None


class Health(BaseModel):
    """Whether the database, the queue and the workers are alive."""

    status: str = Field(description="ok, degraded (no live worker) or unavailable.")
    database: bool
    queue: bool
    queue_kind: str
    pending: int | None = Field(None, description="Job ids waiting in the queue.")
    workers: list[WorkerView]


def _respond(view: jobs.JobView) -> JobResponse:
    base = f"/v1/jobs/{view.id}"
    links = JobLinks(self=base, result=f"{base}/result", report=f"{base}/report")
    return JobResponse(**view.model_dump(), links=links)


ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 404, 409, 413, 415, 422, 503)
}

jobs_router = APIRouter(
    prefix="/v1", tags=["jobs"], dependencies=[Depends(require_api_key)], responses=ERRORS
)
health_router = APIRouter(tags=["health"])


@jobs_router.post(
    "/jobs", status_code=201, response_model=JobResponse, openapi_extra=UPLOAD_OPENAPI
)
async def create_job(request: Request, services: ServicesDep, response: Response) -> JobResponse:
    """Upload a scan (form field ``file``) with an optional ``config`` (PipelineConfig JSON).

    The upload streams to disk; it is checked (header, point count, and every point of files
    up to ``full_check_max_bytes``) before the job is queued.
    """
    upload = await receive_upload(
        request, services.storage, max_bytes=services.settings.max_upload_bytes
    )
    view = await run_in_threadpool(submit, services, upload)
    response.headers["Location"] = f"/v1/jobs/{view.id}"
    return _respond(view)


@jobs_router.get("/jobs", response_model=JobList)
def list_jobs(
    session: SessionDep,
    status: Annotated[jobs.JobStatus | None, Query(description="Only this status.")] = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Query(ge=0, le=1 << 40)] = 0,
) -> JobList:
    """Jobs, newest first, a page at a time."""
    items = jobs.list_jobs(session, status=status, limit=limit, offset=offset)
    total = jobs.count_jobs(session, status=status)
    return JobList(items=[_respond(v) for v in items], total=total, limit=limit, offset=offset)


@jobs_router.get("/jobs/{job_id}", response_model=JobResponse)
def get_job(job_id: JobId, session: SessionDep) -> JobResponse:
    """Status, stage, progress, timings, points and error of one job."""
    return _respond(jobs.get_job(session, job_id))


@jobs_router.get(
    "/jobs/{job_id}/result",
    response_class=FileResponse,
    responses={200: {"content": {"application/octet-stream": {}}}},
)
async def get_result(
    job_id: JobId,
    services: ServicesDep,
    format: Annotated[ResultFormat, Query(description="ply, las or laz.")] = "ply",
) -> FileResponse:
    """The segmented scan with every field of ``jointseg segment`` (409 until it succeeded)."""
    view = await run_in_threadpool(_finished_view, services, job_id)
    if view.status != "succeeded":
        raise JobStateError(f"job {job_id} is {view.status}; no result")
    path = await run_in_threadpool(result_file, services.storage, job_id, format)
    stem = view.filename.rsplit(".", 1)[0]
    return FileResponse(
        path, media_type="application/octet-stream", filename=f"{stem}_segmented.{format}"
    )


@jobs_router.get("/jobs/{job_id}/report", responses={200: {"content": {"application/json": {}}}})
async def get_report(job_id: JobId, services: ServicesDep) -> FileResponse:
    """The job's report.json (as ``jointseg segment --report`` writes it)."""
    view = await run_in_threadpool(_finished_view, services, job_id)
    path = services.storage.report_path(job_id)
    if view.status != "succeeded" or not path.is_file():
        raise JobStateError(f"job {job_id} is {view.status}; no report")
    return FileResponse(path, media_type="application/json")


def _finished_view(services: Services, job_id: str) -> jobs.JobView:
    with services.sessions() as session:
        return jobs.get_job(session, job_id)


@jobs_router.delete(
    "/jobs/{job_id}",
    status_code=202,
    response_model=JobResponse,
    responses={204: {"description": "The finished job and its files were deleted."}},
)
def delete_job(job_id: JobId, services: ServicesDep, session: SessionDep) -> Any:
    """Cancel a queued or running job (202); delete a finished job and its files (204)."""
    view = jobs.get_job(session, job_id)
    if view.status not in FINAL_STATUSES:
        return _respond(jobs.cancel_job(session, job_id))
    jobs.delete_job_row(session, job_id)
    services.storage.delete(job_id)
    return Response(status_code=204)


@health_router.get("/healthz", response_model=Health, responses={503: {"model": Health}})
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
            rows = lifecycle.live_workers(
                session, timeout_s=services.settings.heartbeat_timeout_s
            )
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
