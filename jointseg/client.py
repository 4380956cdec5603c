"""A Python client of the job service, pure HTTP (httpx): submit, wait, download.

It does not import the service: anything that speaks the REST API works, on any machine. httpx
is imported when a client is made, not with this module: the CLI imports it for every command.

Examples
--------
>>> from jointseg.client import JobClient                         # doctest: +SKIP
>>> with JobClient("http://127.0.0.1:8000") as client:            # doctest: +SKIP
...     job = client.submit("room.ply")
...     job = client.wait(job.id)
...     client.download(job.id, "room_segmented.laz")
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ConfigDict

from jointseg.exceptions import ConfigError, JobFailed, ServiceError
from jointseg.io.atomic import atomic_open
from jointseg.progress import ProgressFn

if TYPE_CHECKING:
    import httpx

#: Environment variable holding the API key, when the service needs one.
API_KEY_ENV = "JOINTSEG_API_KEY"
FINAL = ("succeeded", "failed", "cancelled")
RESULT_SUFFIXES = (".ply", ".las", ".laz")


class RemoteJob(BaseModel):
    """A job as the service reports it (the fields a client needs; others are kept too)."""

    model_config = ConfigDict(extra="allow", frozen=True)

    id: str
    filename: str
    status: str
    stage: str | None = None
    progress: float = 0.0
    points: int | None = None
    error: str | None = None
    timings: dict[str, float] | None = None

    @property
    def finished(self) -> bool:
        """Whether the job reached a final status."""
        return self.status in FINAL


def _detail(response: httpx.Response) -> str:
    try:
        body = response.json()
    except ValueError:
        return response.text[:200] or response.reason_phrase
    detail = body.get("detail") if isinstance(body, dict) else body
    return detail if isinstance(detail, str) else json.dumps(detail)[:500]


class JobClient:
    """Talks to one job service.

    Parameters
    ----------
    server : str
        Base URL, e.g. ``http://127.0.0.1:8000``.
    api_key : str, optional
        Sent as ``Authorization: Bearer``; default: ``$JOINTSEG_API_KEY`` when set.
    timeout : float
        Seconds per request (an upload streams for as long as it needs).
    """

    def __init__(self, server: str, *, api_key: str | None = None, timeout: float = 30.0) -> None:
        import httpx

        api_key = api_key or os.environ.get(API_KEY_ENV) or None
        headers = {"Authorization": f"Bearer {api_key}"} if api_key else {}
        self.server = server.rstrip("/")
        self.http = httpx.Client(base_url=self.server, headers=headers, timeout=timeout)

    def __enter__(self) -> JobClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the connection pool."""
        self.http.close()

    def _request(self, method: str, url: str, **kwargs: Any) -> httpx.Response:
        import httpx

        try:
            response = self.http.request(method, url, **kwargs)
        except httpx.HTTPError as exc:
            raise ServiceError(f"{self.server}: cannot reach the job service: {exc}") from exc
        if response.status_code >= 400:
            raise ServiceError(
                f"{method} {url}: {response.status_code} {_detail(response)}",
                status_code=response.status_code,
            )
        return response

    def submit(
        self, path: str | os.PathLike[str], *, config: Mapping[str, Any] | None = None
    ) -> RemoteJob:
        """Upload a scan (streamed from disk) with an optional PipelineConfig as a dict."""
        import httpx

        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"{path}: file not found")
        data = {"config": json.dumps(dict(config))} if config else None
        with open(path, "rb") as fh:
            response = self._request(
                "POST",
                "/v1/jobs",
                files={"file": (path.name, fh, "application/octet-stream")},
                data=data,
                timeout=httpx.Timeout(self.http.timeout.read, write=None),
            )
        return RemoteJob.model_validate(response.json())

    def get(self, job_id: str) -> RemoteJob:
        """The job's current state."""
        return RemoteJob.model_validate(self._request("GET", f"/v1/jobs/{job_id}").json())

    def wait(
        self,
        job_id: str,
        *,
        poll_s: float = 0.5,
        timeout_s: float | None = None,
        progress: ProgressFn | None = None,
    ) -> RemoteJob:
        """Poll until the job finishes; ``progress("job", fraction)`` on every poll.

        Raises
        ------
        JobFailed
            When the job failed or was cancelled (with its error).
        ServiceError
            When the service cannot be reached, or ``timeout_s`` passed.
        """
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            job = self.get(job_id)
            if progress is not None:
                progress("job", job.progress)
            if job.finished:
                if job.status != "succeeded":
                    raise JobFailed(f"job {job_id} {job.status}: {job.error or 'no reason given'}")
                return job
            if deadline is not None and time.monotonic() > deadline:
                raise ServiceError(f"job {job_id} still {job.status} after {timeout_s} s")
            time.sleep(poll_s)

    def download(
        self,
        job_id: str,
        out: str | os.PathLike[str],
        *,
        fmt: str | None = None,
        version: int | None = None,
    ) -> Path:
        """Save the result as ``out`` (format from its suffix: .ply, .las or .laz), atomically;
        of labels ``version`` (0: the machine's own; default: the current one)."""
        import httpx

        out = Path(out)
        fmt = fmt or out.suffix.lower().lstrip(".")
        if f".{fmt}" not in RESULT_SUFFIXES:
            raise ConfigError(f"{out}: results are .ply, .las or .laz files, not {fmt!r}")
        if not out.parent.is_dir():
            raise ConfigError(f"{out}: folder {out.parent} does not exist")
        url = f"/v1/jobs/{job_id}/result"
        try:
            params: dict[str, Any] = {"format": fmt}
            if version is not None:
                params["version"] = version
            with self.http.stream("GET", url, params=params) as response:
                if response.status_code >= 400:
                    response.read()
                    raise ServiceError(
                        f"GET {url}: {response.status_code} {_detail(response)}",
                        status_code=response.status_code,
                    )
                with atomic_open(out) as fh:
                    for chunk in response.iter_bytes(1 << 20):
                        fh.write(chunk)
        except httpx.HTTPError as exc:
            raise ServiceError(f"{self.server}: download failed: {exc}") from exc
        return out

    def report(self, job_id: str) -> dict[str, Any]:
        """The job's report.json."""
        body: dict[str, Any] = self._request("GET", f"/v1/jobs/{job_id}/report").json()
        return body

    def labels(self, job_id: str) -> tuple[dict[str, Any], str]:
        """The job's labels versions (current version and history) and the current ETag."""
        response = self._request("GET", f"/v1/jobs/{job_id}/labels")
        return response.json(), response.headers["ETag"]

    def correct(
        self, job_id: str, edits: list[dict[str, Any]], *, etag: str | None = None
    ) -> tuple[dict[str, Any], str]:
        """Save ``edits`` (``[{"segments": [...], "label": "wall"}, ...]``) as a new labels
        version over the one ``etag`` names (default: the current one, read first).

        Raises
        ------
        ServiceError
            412 when another correction came after ``etag``; 422 naming a bad edit's field.
        """
        if etag is None:
            etag = self.labels(job_id)[1]
        response = self._request(
            "PATCH", f"/v1/jobs/{job_id}/labels", json={"edits": edits}, headers={"If-Match": etag}
        )
        return response.json(), response.headers["ETag"]

    def cancel(self, job_id: str) -> RemoteJob | None:
        """Cancel a queued or running job (its new state), or delete a finished one (None)."""
        response = self._request("DELETE", f"/v1/jobs/{job_id}")
        return None if response.status_code == 204 else RemoteJob.model_validate(response.json())

    def adapt(
        self,
        jobs: list[str],
        *,
        name: str | None = None,
        params: Mapping[str, Any] | None = None,
    ) -> dict[str, Any]:
        """Ask for a model learnt from ``jobs``' corrections (each at its current labels
        version); the queued model (``id``, ``status``, ``weights``: what a later job's
        ``network.weights`` names). Poll it with :meth:`model`.

        Raises
        ------
        ServiceError
            404 / 409 / 422 naming the job (``jobs[1]: no corrected points``).
        """
        body: dict[str, Any] = {"jobs": list(jobs), "params": dict(params or {})}
        if name is not None:
            body["name"] = name
        model: dict[str, Any] = self._request("POST", "/v1/models", json=body).json()
        return model

    def model(self, model_id: str) -> dict[str, Any]:
        """A model's state (and, once it succeeded, its card's ``adapted`` summary)."""
        model: dict[str, Any] = self._request("GET", f"/v1/models/{model_id}").json()
        return model

    def models(self, *, limit: int = 50, offset: int = 0) -> list[dict[str, Any]]:
        """This key's models, newest first (one page)."""
        page = self._request("GET", "/v1/models", params={"limit": limit, "offset": offset})
        items: list[dict[str, Any]] = page.json()["items"]
        return items

    def download_model(self, model_id: str, out: str | os.PathLike[str]) -> Path:
        """Save a succeeded model's checkpoint as ``out`` (for ``jointseg segment --weights``)."""
        out = Path(out)
        response = self._request("GET", f"/v1/models/{model_id}/file")
        with atomic_open(out) as fh:
            fh.write(response.content)
        return out

    def delete_model(self, model_id: str) -> dict[str, Any] | None:
        """Cancel a queued or learning model (its new state), or delete a finished one (None)."""
        response = self._request("DELETE", f"/v1/models/{model_id}")
        if response.status_code == 204:
            return None
        model: dict[str, Any] = response.json()
        return model
