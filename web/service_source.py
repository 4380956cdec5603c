"""The job service's finished jobs as a :class:`web.sources.JobSource`.

Reads the job table through :mod:`server.state.jobs` and the files through
:class:`server.storage.Storage`, so the viewer sees exactly what the API serves, to the same
tenant: :meth:`ServiceSource.for_tenant` is what one signed-in key may see.
"""

from __future__ import annotations

import copy
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

from jointseg.exceptions import JobNotFound, JobStateError
from server.api.auth import Tenant
from server.api.results import result_file
from server.settings import Settings
from server.state.db import make_engine, make_sessions
from server.state.jobs import get_job, list_jobs
from server.storage import ResultFormat, Storage
from web.sources import JobEntry, LabelsInfo

if TYPE_CHECKING:
    from jointseg.labels.edits import EditList

log = logging.getLogger(__name__)

#: Most jobs the picker lists.
PICKER_LIMIT = 200


class ServiceSource:
    """Succeeded jobs of one service (its database and data directory).

    Parameters
    ----------
    settings : Settings
        The service's settings (database URL, data directory).
    owned_by : str, optional
        Only this owner's jobs (:attr:`server.api.auth.Tenant.scope`); None: every job.
    """

    def __init__(self, settings: Settings, *, owned_by: str | None = None) -> None:
        self.engine = make_engine(settings)
        self.sessions = make_sessions(self.engine)
        self.storage = Storage(settings.data_dir)
        self.owned_by = owned_by
        #: The job page's port (the API's), where a job is re-run with another frame
        #: (:mod:`web.frame_panel`): the viewer holds no key to start one itself.
        self.job_page_port: int | None = settings.port
        self.owner: str | None = None  # who saves label versions (the signed-in tenant)

    def for_tenant(self, tenant: Tenant) -> ServiceSource:
        """The jobs ``tenant`` may see, through this source's database connections (close
        only the source they came from)."""
        scoped = copy.copy(self)
        scoped.owned_by = tenant.scope
        scoped.owner = tenant.owner
        return scoped

    def finished_jobs(self) -> list[JobEntry]:
        """Succeeded jobs, newest first."""
        with self.sessions() as session:
            views = list_jobs(
                session, status="succeeded", limit=PICKER_LIMIT, owned_by=self.owned_by
            )
        return [
            JobEntry(id=v.id, filename=v.filename, created_at=v.created_at, points=v.points)
            for v in views
        ]

    def result_path(self, job_id: str) -> Path:
        """The job's result PLY.

        Raises
        ------
        JobNotFound
            For an unknown or malformed id, another owner's job, a job that has not succeeded,
            or deleted files.
        """
        with self.sessions() as session:
            view = get_job(session, job_id, owned_by=self.owned_by)
        if view.status != "succeeded":
            raise JobNotFound(f"job {job_id} is {view.status}: it has no result to show")
        version = self.labels(job_id).version
        corrections = _corrections()
        if version > 0 and corrections is not None:  # the saved version's labels are shown
            path = corrections.version_file(self.storage, job_id, version, "ply")
        else:
            path = self.storage.result_path(job_id, "ply")
        if not path.is_file():
            raise JobNotFound(f"job {job_id}: its result file is gone")
        return path

    def report_path(self, job_id: str) -> Path | None:
        """The job's report.json (the shown labels version's: its objects), None when missing
        or another owner's."""
        try:
            with self.sessions() as session:
                view = get_job(session, job_id, owned_by=self.owned_by)
            path = self.storage.report_path(job_id)
            corrections = _corrections()
            if view.status == "succeeded" and corrections is not None:
                version = self.labels(job_id).version
                if version > 0:
                    path = corrections.version_file(self.storage, job_id, version, "report")
        except (JobNotFound, JobStateError):
            return None
        return path if path.is_file() else None

    def export_path(self, job_id: str, fmt: ResultFormat) -> Path:
        """The job's result as ``fmt`` or its IFC model: the API's own conversion, kept in the
        job's folder, so the viewer and ``GET /v1/jobs/{id}/result`` hand out the same file.

        Raises
        ------
        JobNotFound
            As :meth:`result_path`.
        """
        self.result_path(job_id)  # this tenant's, succeeded, and its files still there
        return result_file(self.storage, job_id, fmt)

    def labels(self, job_id: str) -> LabelsInfo:
        """The job's current labels version and its ETag (:mod:`server.corrections`)."""
        corrections = _corrections()
        if corrections is None:
            return LabelsInfo(refusal="This service keeps no label versions yet.")
        state = corrections.labels_state(
            self.sessions, self.storage, job_id, owned_by=self.owned_by
        )
        history = list(getattr(state, "history", None) or [])
        last = history[-1] if history else None
        corrected = getattr(last, "points_corrected", None)
        if corrected is None and isinstance(last, dict):
            corrected = last.get("points_corrected")
        return LabelsInfo(version=state.version, etag=state.etag, corrected=int(corrected or 0))

    def save_edits(self, job_id: str, edits: EditList, *, if_match: str | None) -> LabelsInfo:
        """``edits`` as the next labels version, as ``PATCH /v1/jobs/{id}/labels`` saves it.

        Raises
        ------
        PreconditionFailed
            Another save came after the version ``if_match`` names.
        """
        corrections = _corrections()
        if corrections is None:
            raise JobStateError("This service keeps no label versions yet.")
        corrections.correct(
            self.sessions, self.storage, job_id, edits,
            if_match=if_match, owner=self.owner, owned_by=self.owned_by,
        )  # fmt: skip
        log.info("labels of job %s saved from the viewer", job_id)
        return self.labels(job_id)

    def close(self) -> None:
        """Release the database connections."""
        self.engine.dispose()


def _corrections() -> Any:
    """:mod:`server.corrections`, None on a service without label versions."""
    try:
        from server import corrections
    except ImportError:
        return None
    return corrections
