"""jointseg's domain errors as HTTP answers: one status per error class, one JSON body shape.

Routes raise domain errors (JobNotFound, ScanFormatError, ...) and never build error responses
themselves; :func:`domain_error` is the app's single handler for all of them.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import Request
from fastapi.responses import JSONResponse

from jointseg.exceptions import (
    AuthenticationError,
    ConfigError,
    JobNotFound,
    JobStateError,
    JointsegError,
    QueueUnavailable,
    ScanFormatError,
    UnsupportedFormatError,
    UploadTooLarge,
)
from server.schemas import ErrorBody

log = logging.getLogger(__name__)

#: HTTP status of each domain error; the most specific class listed first wins.
ERROR_STATUS: tuple[tuple[type[JointsegError], int], ...] = (
    (AuthenticationError, 401),
    (JobNotFound, 404),
    (JobStateError, 409),
    (UploadTooLarge, 413),
    (UnsupportedFormatError, 415),
    (ScanFormatError, 422),
    (ConfigError, 422),
    (QueueUnavailable, 503),
)

#: The error answers of the /v1 routes, for OpenAPI.
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 404, 409, 413, 415, 422, 503)
}
ERROR_RESPONSES[404]["description"] = (
    "No such job, or another API key's job (the same answer: existence does not leak)"
)


def status_for(exc: JointsegError) -> int:
    """The HTTP status of a domain error (400 for one not listed)."""
    for cls, status in ERROR_STATUS:
        if isinstance(exc, cls):
            return status
    return 400


async def domain_error(request: Request, exc: Exception) -> JSONResponse:
    """The one handler mapping jointseg's errors to a status and ``{"detail", "error"}``."""
    assert isinstance(exc, JointsegError)
    status = status_for(exc)
    headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
    if status >= 500:
        log.error("%s %s: %s", request.method, request.url.path, exc)
    return JSONResponse(
        {"detail": str(exc), "error": type(exc).__name__}, status_code=status, headers=headers
    )
