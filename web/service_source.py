"""The job service's finished jobs as a :class:`web.sources.JobSource`.

Reads the job table through :mod:`server.state.jobs` and the files through
:class:`server.storage.Storage`, so the viewer sees exactly what the API serves, to the same
tenant: :meth:`ServiceSource.for_tenant` is what one signed-in key may see.
"""

from __future__ import annotations

import copy
from pathlib import Path

from jointseg.exceptions import JobNotFound
from server.api.auth import Tenant
from server.api.results import result_file
from server.settings import Settings
from server.state.db import make_engine, make_sessions
from server.state.jobs import get_job, list_jobs
from server.storage import ResultFormat, Storage
from web.sources import JobEntry

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

    def for_tenant(self, tenant: Tenant) -> ServiceSource:
        """The jobs ``tenant`` may see, through this source's database connections (close
        only the source they came from)."""
        scoped = copy.copy(self)
        scoped.owned_by = tenant.scope
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
        path = self.storage.result_path(job_id, "ply")
        if not path.is_file():
            raise JobNotFound(f"job {job_id}: its result file is gone")
        return path

    def report_path(self, job_id: str) -> Path | None:
        """The job's report.json, None when missing or another owner's."""
        try:
            with self.sessions() as session:
                get_job(session, job_id, owned_by=self.owned_by)
            path = self.storage.report_path(job_id)
        except JobNotFound:
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

    def close(self) -> None:
        """Release the database connections."""
        self.engine.dispose()
