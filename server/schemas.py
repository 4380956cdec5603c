"""The API's request and response bodies (pydantic), apart from the tables in
:mod:`server.state.models`: what clients see never leaks an ORM object or a column they should not.
"""

from __future__ import annotations

from datetime import datetime
from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field

from jointseg.frame.params import FrameParams

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]
#: Every status a job can have (the job table's ``status`` column, :mod:`server.state.models`),
#: and the final ones. Here, below the job table: its functions answer with these models, so
#: the table's package imports this module and never the other way round.
STATUSES: tuple[JobStatus, ...] = get_args(JobStatus)
FINAL_STATUSES: tuple[JobStatus, ...] = ("succeeded", "failed", "cancelled")


class TileCounts(BaseModel):
    """How far the tiles of a job whose scan was cut into tiles have come."""

    total: int = Field(description="Tiles in the job's plan.")
    done: int = Field(description="Tiles finished.")
    running: int = Field(description="Tiles a worker is running now.")


class JobView(BaseModel):
    """A job as the API shows it (built from a job row)."""

    model_config = ConfigDict(from_attributes=True)

    id: str = Field(description="32 hex digits.")
    filename: str = Field(description="The uploaded file's name (no folders).")
    format: str = Field(description="Scan format read from the extension (ply, las, ...).")
    status: JobStatus
    stage: str | None = Field(
        None,
        description="Current stage: read, network, geometry, ...; for a tiled scan plan, "
        "`tiles 3/8` (tiles done), join, fusion, write.",
    )
    progress: float = Field(0.0, ge=0, le=1, description="Overall progress, 0 to 1.")
    points: int | None = Field(None, description="Points in the scan (from the upload's header).")
    timings: dict[str, float] | None = Field(None, description="Seconds per stage and total.")
    error: str | None = Field(None, description="Why the job failed or was cancelled.")
    network: str = Field(description="Network backend (randlanet, dgcnn).")
    quality: str = Field("standard", description="Quality preset: fast, standard or best.")
    attempts: int = Field(0, description="Times a worker started the job.")
    tiles: TileCounts | None = Field(
        None,
        description="For a scan cut into tiles (more points than the config's "
        "`tiles.max_points`), run by any number of workers: the tiles' counts; null otherwise.",
    )
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    labels_version: int = Field(
        0,
        description="The current labels version: 0 is the run's own labels, each correction "
        "(`PATCH /v1/jobs/{id}/labels`) adds one.",
    )
    rerun_of: str | None = Field(
        None, description="The job this one re-runs with another frame (`POST .../rerun`)."
    )

    @property
    def finished(self) -> bool:
        """Whether the job reached a final status."""
        return self.status in FINAL_STATUSES


class JobLinks(BaseModel):
    """Where to find a job and its outputs."""

    self: str
    result: str
    report: str


class JobResponse(JobView):
    """A job with links to itself, its result and its report."""

    links: JobLinks

    @classmethod
    def from_view(cls, view: JobView) -> JobResponse:
        """``view`` with its links (``/v1/jobs/<id>``, ``.../result``, ``.../report``)."""
        base = f"/v1/jobs/{view.id}"
        links = JobLinks(self=base, result=f"{base}/result", report=f"{base}/report")
        return cls(**view.model_dump(), links=links)


class LabelsVersion(BaseModel):
    """One labels version of a job, as its history lists it."""

    version: int = Field(description="0 is the run's own labels; each correction adds one.")
    created_at: datetime | None = Field(
        description="When the version was made (version 0: when the job finished)."
    )
    owner: str | None = Field(
        None, description="Hash of the API key that made it (the job's owner for version 0)."
    )
    points_changed: int = Field(0, description="Points whose label this version's edits changed.")
    points_corrected: int = Field(0, description="Points whose label differs from version 0's.")
    edits: int = Field(0, description="Edits in the request that made it.")


class LabelsState(BaseModel):
    """A job's current labels version and every version before it (oldest first)."""

    job_id: str
    version: int = Field(description="The current version (what downloads give by default).")
    etag: str = Field(description='The current version\'s ETag (`"v3"`): send it as `If-Match`.')
    history: list[LabelsVersion]


class RerunRequest(BaseModel):
    """``POST /v1/jobs/{id}/rerun``: the frame settings to change; the rest of the job's
    config stays."""

    model_config = ConfigDict(extra="forbid")

    frame: FrameParams = Field(
        description='Frame settings over the job\'s own, e.g. `{"up": "+y", "units": "mm", '
        '"level": true}`: only the fields given change.'
    )


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
    """Whether the service is up; with an accepted key (or on an open service) also the
    database, the queue and the workers. Without a key a locked service answers ``status``
    only: no host name, process ids or job ids for anonymous callers."""

    status: str = Field(description="ok, degraded (no live worker) or unavailable.")
    database: bool | None = Field(None, description="Whether the job table answers (with a key).")
    queue: bool | None = Field(None, description="Whether the queue answers (with a key).")
    queue_kind: str | None = Field(None, description="sqlite, postgres or redis (with a key).")
    pending: int | None = Field(None, description="Job ids waiting in the queue (with a key).")
    workers: list[WorkerView] | None = Field(
        None,
        description="Live workers (with a key); a job id only when the key may see that job.",
    )


class ModelParams(BaseModel):
    """How a model learns (:class:`jointseg.adapt.head.AdaptParams`, within the service's
    bounds); a field left out takes the library's default, chosen on the tuning scans."""

    model_config = ConfigDict(extra="forbid")

    steps: int | None = Field(None, ge=1, le=20_000, description="Steps of the head's fit (300).")
    lr: float | None = Field(None, gt=0, le=1, description="Learning rate (0.002).")
    keep_weight: float | None = Field(
        None, ge=0, le=1000, description="Weight of holding uncorrected points to the base (8)."
    )
    replay_rooms: int | None = Field(
        None, ge=0, le=20, description="Generated rooms that keep the other classes' labels (4)."
    )
    min_base_probability: float | None = Field(
        None,
        ge=0,
        lt=1,
        description="A corrected point whose class the bundled network gives less than this is "
        "not learnt from where such points are a minority of its corrected segment (another "
        "object the segment held); 0.01; 0 learns from every corrected point.",
    )
    seed: int | None = Field(None, ge=0, le=2**31 - 1)


class ModelRequest(BaseModel):
    """``POST /v1/models``: the corrected jobs a model learns from (their latest labels
    versions), a name for it and how it learns."""

    model_config = ConfigDict(extra="forbid")

    jobs: list[str] = Field(
        min_length=1,
        max_length=100,
        description="Ids of the caller's succeeded jobs, each corrected at least once "
        "(`PATCH /v1/jobs/{id}/labels`); their current labels versions are used.",
    )
    name: str | None = Field(None, max_length=200, description="A name to know it by.")
    params: ModelParams = Field(default_factory=ModelParams)


class ModelSource(BaseModel):
    """One corrected job a model learns from, and the labels version it was given."""

    job_id: str
    version: int


class ModelView(BaseModel):
    """A model learnt from corrections, as the API shows it (built from its job row)."""

    id: str = Field(description="32 hex digits.")
    name: str | None = None
    status: JobStatus
    stage: str | None = Field(None, description="sources, features or adapt while it runs.")
    progress: float = Field(0.0, ge=0, le=1)
    error: str | None = Field(None, description="Why it failed or was cancelled.")
    attempts: int = 0
    sources: list[ModelSource] = Field(description="The jobs and labels versions it learns from.")
    params: dict[str, float | int] = Field(description="The learning settings asked for.")
    adapted: dict[str, Any] | None = Field(
        None,
        description="When it succeeded: the model card's `adapted` section (each scan with its "
        "version and corrected points, the params, the seconds taken).",
    )
    weights: str = Field(description='What a later job names in `network.weights`: "model:<id>".')
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None

    @property
    def finished(self) -> bool:
        """Whether the model reached a final status."""
        return self.status in FINAL_STATUSES


class ModelLinks(BaseModel):
    """Where to find a model and its file."""

    self: str
    file: str


class ModelResponse(ModelView):
    """A model with links to itself and its file."""

    links: ModelLinks

    @classmethod
    def from_view(cls, view: ModelView) -> ModelResponse:
        """``view`` with its links (``/v1/models/<id>``, ``.../file``)."""
        base = f"/v1/models/{view.id}"
        return cls(**view.model_dump(), links=ModelLinks(self=base, file=f"{base}/file"))


class ModelList(BaseModel):
    """One page of models, newest first."""

    items: list[ModelResponse]
    total: int
    limit: int
    offset: int
