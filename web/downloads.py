"""The files a viewer tab offers to download: the job page's six, under the API's names.

A surveyor wants the points as LAS or LAZ, a BIM engineer the IFC model, everyone the report.
A tab holds no key (it is signed in with a session cookie: :mod:`web.sessions`), so it cannot
fetch the API's addresses; it reads the same files through its source instead
(:meth:`web.sources.JobSource.export_path`: on the service, the API's own conversion and cache)
and sends the bytes over its websocket. No address is involved, so none can carry a key.
"""

from __future__ import annotations

import logging

import viser

from jointseg.exceptions import JobNotFound, JointsegError
from server.messages import public_report_bytes, without_server_paths
from server.results import Download, download_name, layout_from
from web.sources import JobSource

log = logging.getLogger(__name__)

#: The buttons' labels.
LABELS: dict[Download, str] = {
    "ply": "PLY",
    "las": "LAS",
    "laz": "LAZ",
    "report": "Report",
    "objects": "objects.json",
    "ifc": "IFC",
}
#: Downloads that need the report's objects and rooms.
NEEDS_LAYOUT: frozenset[Download] = frozenset({"objects", "ifc"})


def download_body(source: JobSource, job_id: str, kind: Download) -> bytes:
    """The bytes of one download, as the API's route for it answers them.

    The report names the weights by file name only (:func:`server.messages.public_report`);
    objects.json is the report's objects and rooms, as ``GET /v1/jobs/{id}/objects`` gives.

    Raises
    ------
    JobNotFound
        The job is gone, not this tenant's, or has no report.
    JobStateError
        The run found no objects or rooms (objects.json, IFC).
    """
    if kind == "report" or kind == "objects":
        report = source.report_path(job_id)
        if report is None:
            raise JobNotFound(f"job {job_id} has no report")
        if kind == "report":
            return public_report_bytes(report)
        return layout_from(report).model_dump_json(indent=2).encode("utf-8")
    return source.export_path(job_id, kind).read_bytes()


def file_name(filename: str | None, job_id: str, kind: Download, version: int = 0) -> str:
    """The download's name: the API's for the job's file (naming a corrected labels
    version), else from its id."""
    return download_name(filename or f"{job_id}.ply", kind, version)


def has_layout(report: dict[str, object] | None) -> bool:
    """Whether a report holds objects and rooms (objects.json and IFC can be made)."""
    return isinstance(report, dict) and isinstance(report.get("rooms"), dict)


def send_download(
    client: viser.ClientHandle,
    source: JobSource,
    job_id: str,
    kind: Download,
    filename: str | None = None,
) -> None:
    """One of a job's downloads, sent over the tab's websocket as ``filename``'s download name;
    a download that cannot be made is told in a notification, never with a server path."""
    try:
        version = source.labels(job_id).version
    except JointsegError:
        version = 0  # the download itself then says why it cannot be made
    name = file_name(filename, job_id, kind, version)
    busy = client.add_notification(f"Preparing {name}", "", loading=True, with_close_button=False)
    try:
        body = download_body(source, job_id, kind)
    except JointsegError as exc:
        log.warning("job %s: no %s download: %s", job_id, kind, exc)
        client.add_notification("Cannot download", without_server_paths(str(exc)), color="red")
        return
    except (OSError, ValueError):  # the message would name a path: say what, not where
        log.warning("job %s: its %s download could not be read", job_id, kind)
        client.add_notification("Cannot download", f"{job_id}: unreadable", color="red")
        return
    finally:
        busy.remove()
    client.send_file_download(name, body, save_immediately=True)
