"""Every error as an HTTP answer of one shape: ``{"error": <name>, "detail": <one line>}``.

Routes raise domain errors (JobNotFound, ScanFormatError, ...) and never build error responses
themselves; :func:`domain_error` is the app's single handler for all of them. The framework's own
answers get the same shape: request validation (:func:`validation_error`, 422), unknown routes
and wrong methods (:func:`http_error`, 404 / 405 with ``Allow``) and anything unexpected
(:func:`internal_error`, 500, details only in the log). :func:`install_error_handlers` wires all
four into an app.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from jointseg.exceptions import (
    AuthenticationError,
    ConfigError,
    Forbidden,
    JobNotFound,
    JobStateError,
    JointsegError,
    PreconditionFailed,
    PreconditionRequired,
    QueueUnavailable,
    ScanFormatError,
    UnsupportedFormatError,
    UploadTooLarge,
)
from server.messages import MAX_MESSAGE, one_line
from server.schemas import ErrorBody

log = logging.getLogger(__name__)

#: HTTP status of each domain error; the most specific class listed first wins.
ERROR_STATUS: tuple[tuple[type[JointsegError], int], ...] = (
    (AuthenticationError, 401),
    (Forbidden, 403),
    (JobNotFound, 404),
    (JobStateError, 409),
    (PreconditionFailed, 412),
    (PreconditionRequired, 428),
    (UploadTooLarge, 413),
    (UnsupportedFormatError, 415),
    (ScanFormatError, 422),
    (ConfigError, 422),
    (QueueUnavailable, 503),
)

#: Longest ``detail`` sent (a message is cut, with an ellipsis, beyond it).
MAX_DETAIL = MAX_MESSAGE
#: Validation problems listed in one 422 (the rest counted).
MAX_PROBLEMS = 5

#: What each error status means, for OpenAPI.
ERROR_MEANINGS: dict[int, str] = {
    401: "Missing or refused API key",
    403: "An accepted key without the right to this request (`/metrics`: admin keys only)",
    404: "No such job, or another API key's job (the same answer: existence does not leak), "
    "or no such route",
    405: "Method not allowed on this path; `Allow` lists those that are",
    409: "The job is not in a state for this (not finished, not succeeded, nothing found)",
    412: "`If-Match` names a labels version that is no longer the current one: read the "
    "labels again (their `ETag`) and repeat the change on top of them",
    413: "Upload larger than the service takes",
    415: "Not a scan format jointseg reads",
    422: "Invalid request, config or scan; `detail` names the field or the problem",
    428: "`If-Match` is missing: a change to the labels names the version it builds on (the "
    "`ETag` of `GET /v1/jobs/{id}/labels`)",
    500: "Unexpected error (its details are only in the service log)",
    503: "The queue is unavailable",
}


def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` for these error statuses: each an :class:`ErrorBody` (405 with
    its ``Allow`` header)."""
    responses: dict[int | str, dict[str, Any]] = {}
    for code in codes:
        responses[code] = {"model": ErrorBody, "description": ERROR_MEANINGS[code]}
        if code == 405:
            responses[code]["headers"] = {
                "Allow": {"description": "The path's methods.", "schema": {"type": "string"}}
            }
    return responses


#: The error answers every /v1 route can give (routes add their own: 409, 413, ...).
ERROR_RESPONSES = error_responses(401, 404, 405, 422, 500)
ERROR_RESPONSES[404]["description"] = (
    "No such job, or another API key's job (the same answer: existence does not leak)"
)


def status_for(exc: JointsegError) -> int:
    """The HTTP status of a domain error (400 for one not listed)."""
    for cls, status in ERROR_STATUS:
        if isinstance(exc, cls):
            return status
    return 400


def error_response(
    status: int, error: str, detail: str, headers: Mapping[str, str] | None = None
) -> JSONResponse:
    """The body every error has: ``{"detail", "error"}``, ``detail`` on one line."""
    return JSONResponse(
        {"detail": one_line(detail), "error": error}, status_code=status, headers=headers
    )


async def domain_error(request: Request, exc: Exception) -> JSONResponse:
    """The one handler mapping jointseg's errors to a status and ``{"detail", "error"}``."""
    assert isinstance(exc, JointsegError)
    status = status_for(exc)
    headers = {"WWW-Authenticate": "Bearer"} if status == 401 else None
    if status >= 500:
        log.error("%s %s: %s", request.method, request.url.path, exc)
    return error_response(status, type(exc).__name__, str(exc), headers)


def _problem(error: Any) -> str:
    """One validation problem as ``where: what`` (``query.limit: Input should be ...``)."""
    where = ".".join(str(part) for part in error.get("loc", ())) or "request"
    return f"{where}: {error.get('msg', 'invalid')}"


async def validation_error(request: Request, exc: Exception) -> JSONResponse:
    """A request FastAPI could not parse (422): each problem named by where it is, without
    echoing the input back."""
    assert isinstance(exc, RequestValidationError)
    errors = list(exc.errors())
    problems = [_problem(e) for e in errors[:MAX_PROBLEMS]]
    if len(errors) > MAX_PROBLEMS:
        problems.append(f"and {len(errors) - MAX_PROBLEMS} more")
    return error_response(422, "RequestValidationError", "; ".join(problems) or "invalid request")


def http_status_name(status: int) -> str:
    """``NotFound`` for 404, ``MethodNotAllowed`` for 405: the status's phrase as a name."""
    try:
        phrase = HTTPStatus(status).phrase
    except ValueError:
        return "HTTPError"
    return re.sub(r"[^A-Za-z]", "", phrase.title())


async def http_error(request: Request, exc: Exception) -> JSONResponse:
    """The framework's own errors (unknown route 404, wrong method 405 with its ``Allow``
    header, and any ``HTTPException`` a route raises) in the one shape."""
    assert isinstance(exc, StarletteHTTPException)
    status = exc.status_code
    if status == 404 and exc.detail == HTTPStatus.NOT_FOUND.phrase:
        detail = f"no route {request.url.path}"
    elif status == 405:
        detail = f"{request.method} is not allowed on {request.url.path}"
    else:
        detail = str(exc.detail)
    return error_response(status, http_status_name(status), detail, exc.headers)


async def internal_error(request: Request, exc: Exception) -> JSONResponse:
    """Anything unexpected (500): the client learns only that it happened; the traceback goes
    to the log (Starlette logs it again after this answer)."""
    log.error("%s %s: unexpected %s", request.method, request.url.path, type(exc).__name__)
    return error_response(500, "InternalError", "internal error; the service log has the details")


def install_error_handlers(app: FastAPI) -> None:
    """Give every error ``app`` can answer the one shape."""
    app.add_exception_handler(JointsegError, domain_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(Exception, internal_error)
