"""Domain errors raised by jointseg.

Every error a user can cause carries a message that names what is wrong and where, so the CLI
can print it as is and the service can map each class to one HTTP status.
"""

from __future__ import annotations

import re


class JointsegError(Exception):
    """Base class of every error jointseg raises on purpose."""


class ScanFormatError(JointsegError, ValueError):
    """A scan file (or array) is malformed, unsupported or too large.

    The message says what is wrong and, where it can, which line, element or field.
    """


class ConfigError(JointsegError, ValueError):
    """A configuration value is invalid; the message names the parameter and the value."""


class Cancelled(JointsegError):
    """Work was stopped because its cancel event was set."""


class UnsupportedFormatError(ScanFormatError):
    """A file's extension names no format jointseg reads (the message lists the ones it does)."""


# Errors of the job service (server/) and its HTTP client (jointseg.client), kept here so the
# service maps each class to one status code and the CLI prints every one as a single line.


class JobNotFound(JointsegError, LookupError):
    """No job has this id (or it was deleted)."""


class JobStateError(JointsegError):
    """The job is not in a state that allows the request (e.g. a result before it succeeded)."""


class UploadTooLarge(JointsegError):
    """An upload (or one of its form fields) is larger than the configured limit."""


class AuthenticationError(JointsegError):
    """A request lacks a valid API key."""


class Forbidden(JointsegError):
    """An accepted key without the right to this request (``/metrics``: admin keys only)."""


class QueueUnavailable(JointsegError):
    """The job queue (SQLite, PostgreSQL or Redis) cannot be reached."""


class PreconditionRequired(JointsegError):
    """A change that must name the version it builds on (``If-Match``) did not name one."""


class PreconditionFailed(JointsegError):
    """A change named a version that is no longer the current one (another change came first)."""


class ServiceError(JointsegError):
    """The job service answered a request with an error (client side).

    Attributes
    ----------
    status_code : int
        HTTP status, 0 when the service could not be reached at all.
    """

    def __init__(self, message: str, *, status_code: int = 0) -> None:
        super().__init__(message)
        self.status_code = status_code


class JobFailed(JointsegError):
    """A job the client waited for ended failed or cancelled; the message carries its error."""


#: A path inside a message: absolute POSIX (``/project/src/x.cpp``), home or Windows, or a C++
#: source file; a library's message holding one is not passed on.
_PATH_IN_TEXT = re.compile(
    r"(?:^|[\s'\"(=:,\[])(?:/|~/|[A-Za-z]:\\)[\w.~-]|\.(?:cpp|cc|cxx|hpp|h)\b|enforce fail"
)
#: libE57Format's error-code tag at the end of its first line: ``(ErrorBadChecksum)``.
_ERROR_CODE_TAG = re.compile(r"\s*\(Error\w+\)\s*$")
#: Longest reason taken over from a library's message.
MAX_REASON = 200


def library_reason(exc: BaseException, fallback: str = "the file is corrupt or truncated") -> str:
    """The first line of a third-party library's message, fit to show a user, else ``fallback``.

    Why: libraries such as libE57Format (through pye57) and torch put their debug text, C++
    source paths and the server's file paths into their messages, over many lines. A user is
    told what is wrong in one sentence: the first line is kept when it is short and names no
    path; otherwise ``fallback`` says it in the project's words.
    """
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    if not lines:
        return fallback
    first = _ERROR_CODE_TAG.sub("", lines[0]).strip().rstrip(":").strip()
    if not first or len(first) > MAX_REASON or _PATH_IN_TEXT.search(first):
        return fallback
    return first
