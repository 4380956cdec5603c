"""The job service's finished jobs as a :class:`web.sources.JobSource`.

Reads the job table through :mod:`server.state.jobs` and the files through
:class:`server.storage.Storage`, so the viewer sees exactly what the API serves.
"""

from __future__ import annotations

from pathlib import Path

from jointseg.exceptions import JobNotFound
from server.settings import Settings
from server.state.db import make_engine, make_sessions
from server.state.jobs import get_job, list_jobs
from server.storage import Storage
from web.sources import JobEntry

#: Most jobs the picker lists.
PICKER_LIMIT = 200


class ServiceSource:
    """Succeeded jobs of one service (its database and data directory).

    Parameters
    ----------
    settings : Settings
        The service's settings (database URL, data directory).
    """

    def __init__(self, settings: Settings) -> None:
        self.engine = make_engine(settings)
        self.sessions = make_sessions(self.engine)
        self.storage = Storage(settings.data_dir)

    def finished_jobs(self) -> list[JobEntry]:
        """Succeeded jobs, newest first."""
        with self.sessions() as session:
            views = list_jobs(session, status="succeeded", limit=PICKER_LIMIT)
        return [
            JobEntry(id=v.id, filename=v.filename, created_at=v.created_at, points=v.points)
            for v in views
        ]

    def result_path(self, job_id: str) -> Path:
        """The job's result PLY.

        Raises
        ------
        JobNotFound
            For an unknown or malformed id, a job that has not succeeded, or deleted files.
        """
        with self.sessions() as session:
            view = get_job(session, job_id)
        if view.status != "succeeded":
            raise JobNotFound(f"job {job_id} is {view.status}: it has no result to show")
        path = self.storage.result_path(job_id, "ply")
        if not path.is_file():
            raise JobNotFound(f"job {job_id}: its result file is gone")
        return path

    def report_path(self, job_id: str) -> Path | None:
        """The job's report.json, None when missing."""
        try:
            path = self.storage.report_path(job_id)
        except JobNotFound:
            return None
        return path if path.is_file() else None

    def close(self) -> None:
        """Release the database connections."""
        self.engine.dispose()
