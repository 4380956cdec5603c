"""A tab's job picker: the finished jobs its source lists, kept current without a reload.

The viewer re-reads every tab's list every :data:`web.viewer.LIST_EVERY_S` seconds, so jobs
deleted or finished elsewhere leave or join the list; the picker is sent again only when its
list changed (an open dropdown is not redrawn under the mouse). A failed listing keeps the last
list: a database hiccup is no reason to call every job gone.
"""

from __future__ import annotations

import logging
from pathlib import Path

import viser

from jointseg.exceptions import JointsegError
from web.controls import NO_JOBS, PLACEHOLDER
from web.scene import SceneCache, SceneData
from web.sources import JobEntry, JobSource

log = logging.getLogger(__name__)


class JobList:
    """The finished jobs of one tab's source and the picker that offers them.

    Parameters
    ----------
    picker : viser.GuiDropdownHandle
        The *Job* dropdown.
    source : JobSource
    """

    def __init__(self, picker: viser.GuiDropdownHandle[str], source: JobSource) -> None:
        self.picker = picker
        self.source = source
        self.entries: dict[str, JobEntry] = {}
        self._labels: dict[str, str] = {}  # picker text -> job id
        self._listed = False  # the picker has been sent a list
        self._failed = False

    def refresh(self, shown: str | None = None) -> str | None:
        """Read the list again and send it to the picker when it changed, keeping the current
        choice (a choice that left the list falls back to the placeholder). Returns the name of
        the ``shown`` job when it is gone (deleted, or no longer this key's), else None."""
        try:
            jobs = list(self.source.finished_jobs())
        except Exception:  # the list is best effort: a hiccup must not kill the tab
            if not self._failed:
                log.exception("listing finished jobs failed")
            self._failed = True
            return None  # keep the last list: a hiccup is no reason to call every job gone
        self._failed = False
        known = dict(self.entries)
        labels = {job.label: job.id for job in jobs}
        self.entries = {job.id: job for job in jobs}
        if labels != self._labels or not self._listed:
            self._labels, self._listed = labels, True
            current = self.picker.value
            self.picker.options = (PLACEHOLDER if jobs else NO_JOBS, *labels)
            if current in labels:
                self.picker.value = current  # type: ignore[misc]  # viser types it read-only
        if shown is None or shown in self.entries or not self.gone(shown):
            return None  # shown, or beyond the list's length (it holds the newest jobs only)
        entry = known.get(shown)
        return f"{entry.filename} [{shown[:8]}]" if entry is not None else shown

    def load(self, job_id: str, cache: SceneCache) -> SceneData:
        """A job's result (and report) through the viewer's cache.

        Raises
        ------
        JointsegError, OSError
            The job is not this source's, or its files cannot be read.
        """
        return cache.load(self.source.result_path(job_id), self.source.report_path(job_id))

    def gone(self, job_id: str) -> bool:
        """Whether a job is no longer on the source (deleted, or no longer this key's)."""
        try:
            self.source.result_path(job_id)
        except JointsegError as exc:
            log.info("job %s is gone: %s", job_id, exc)
            return True
        return False

    def job_of(self, label: str) -> str | None:
        """The job id behind a picker text (None for the placeholder)."""
        return self._labels.get(label)

    def label_of(self, job_id: str) -> str | None:
        """The picker text of a job (None when it is not listed)."""
        return next((label for label, i in self._labels.items() if i == job_id), None)

    def name(self, job_id: str) -> str:
        """``file.ply [abcd1234]`` for a listed job, else its id."""
        entry = self.entries.get(job_id)
        return f"{entry.filename} [{job_id[:8]}]" if entry is not None else job_id

    def stem(self, job_id: str | None) -> str:
        """The uploaded file's name without its suffix, to name a screenshot after."""
        filename = self.filename(job_id)
        return Path(filename).stem if filename else (job_id or "view")

    def filename(self, job_id: str | None) -> str | None:
        """The uploaded file's name of a listed job."""
        entry = self.entries.get(job_id or "")
        return None if entry is None else entry.filename
