"""The job service's finished jobs as a :class:`web.sources.JobSource`.

Reads the job table through :mod:`server.state.jobs` and the files through
:class:`server.storage.Storage`, so the viewer sees exactly what the API serves, to the same
tenant: :meth:`ServiceSource.for_tenant` is what one signed-in key may see.
"""

from __future__ import annotations

import copy
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from jointseg.exceptions import JobNotFound, JobStateError
from server.api.auth import Tenant
from server.corrections import VersionKind, correct, labels_state, version_file
from server.schemas import JobView
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

    def _succeeded(self, job_id: str) -> JobView:
        """The job as this tenant sees it, when it succeeded.

        Raises
        ------
        JobNotFound
            For an unknown or malformed id, another owner's job, or a job that has not
            succeeded.
        """
        with self.sessions() as session:
            view = get_job(session, job_id, owned_by=self.owned_by)
        if view.status != "succeeded":
            raise JobNotFound(f"job {job_id} is {view.status}: it has no result to show")
        return view

    def _version_file(self, job_id: str, kind: VersionKind) -> Path:
        """The current labels version's ``kind`` file (version 0: the run's own), as the API's
        downloads give it by default."""
        view = self._succeeded(job_id)
        try:
            path = version_file(self.storage, job_id, view.labels_version, kind)
        except JobStateError as exc:
            raise JobNotFound(f"job {job_id}: its files are gone ({exc})") from None
        if not path.is_file():
            raise JobNotFound(f"job {job_id}: its result file is gone")
        return path

    def result_path(self, job_id: str) -> Path:
        """The job's result PLY, of its current labels version.

        Raises
        ------
        JobNotFound
            For an unknown or malformed id, another owner's job, a job that has not succeeded,
            or deleted files.
        """
        return self._version_file(job_id, "ply")

    def report_path(self, job_id: str) -> Path | None:
        """The job's report.json (the current labels version's: its objects), None when
        missing or another owner's."""
        try:
            return self._version_file(job_id, "report")
        except (JobNotFound, JobStateError):
            return None

    def export_path(self, job_id: str, fmt: ResultFormat) -> Path:
        """The job's result as ``fmt`` or its IFC model, of its current labels version: the
        API's own files, kept in the job's folder, so the viewer and ``GET
        /v1/jobs/{id}/result`` hand out the same file.

        Raises
        ------
        JobNotFound
            As :meth:`result_path`.
        """
        view = self._succeeded(job_id)
        return version_file(self.storage, job_id, view.labels_version, fmt)

    def labels(self, job_id: str) -> LabelsInfo:
        """The job's current labels version, its ETag and the points it corrects."""
        state = labels_state(self.sessions, self.storage, job_id, owned_by=self.owned_by)
        corrected = state.history[-1].points_corrected if state.version else 0
        return LabelsInfo(version=state.version, etag=state.etag, corrected=corrected)

    def save_edits(self, job_id: str, edits: EditList, *, if_match: str | None) -> LabelsInfo:
        """``edits`` as the next labels version, as ``PATCH /v1/jobs/{id}/labels`` saves it.

        Raises
        ------
        PreconditionFailed
            Another save came after the version ``if_match`` names.
        """
        correct(
            self.sessions, self.storage, job_id, edits,
            if_match=if_match, owner=self.owner, owned_by=self.owned_by,
        )  # fmt: skip
        log.info("labels of job %s saved from the viewer", job_id)
        return self.labels(job_id)

    def close(self) -> None:
        """Release the database connections."""
        self.engine.dispose()
