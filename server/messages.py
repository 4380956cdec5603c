"""Error messages and reports a client sees: they name the user's file, never a path on the server.

Readers and the pipeline report errors with the path they were given, which on the service is
the stored upload (``data/jobs/<id>/upload.ply``); both the upload check and the worker put
the client's file name back before the message reaches the API.
"""

from __future__ import annotations

import json
import re
from pathlib import Path, PureWindowsPath
from typing import Any

#: Longest message a client is given (cut, with an ellipsis, beyond it).
MAX_MESSAGE = 1000
#: An absolute POSIX path inside a sentence (``/srv/weights/w.pt``).
_ABSOLUTE = re.compile(r"(?<![\w.:/~>\]])/[^/\s'\"(),;]+(?:/[^/\s'\"(),;]*)*")


def one_line(message: str, limit: int = MAX_MESSAGE) -> str:
    """``message`` on one line (line breaks and runs of blanks become one space), cut at
    ``limit`` characters: a client's error is a sentence, not a library's dump."""
    text = re.sub(r"\s+", " ", message).strip()
    return text if len(text) <= limit else text[: limit - 1].rstrip() + "…"


def without_server_paths(message: str) -> str:
    """``message`` with every absolute path reduced to its file name.

    Why: the readers and loaders name the file they opened, which on the service is a path on
    the server (an upload, the weights); the ones the caller knows are replaced by the user's
    names first, and this catches whatever else a message carries.
    """
    return _ABSOLUTE.sub(lambda m: [p for p in m.group(0).split("/") if p][-1], message)


def public_message(
    exc: BaseException, path: Path, filename: str, names: dict[str, str] | None = None
) -> str:
    """``exc``'s message as a client sees it: ``path`` (and each key of ``names``) replaced by
    the user's name for it, any other server path by its file name, on one line."""
    text = str(exc).replace(str(path), filename)
    for server, user in (names or {}).items():
        text = text.replace(server, user)
    return one_line(without_server_paths(text))


def _server_path(text: str) -> bool:
    """Whether ``text`` is a whole absolute path (POSIX, Windows or ``~``), one line."""
    if "\n" in text or len(text) > 4096:
        return False
    return text.startswith(("/", "~")) or PureWindowsPath(text).is_absolute()


def public_report(body: Any) -> Any:
    """A report with every value that is a path on the server reduced to its file name.

    The pipeline records the weights it used as the resolved path
    (``.../jointseg/network/weights/randlanet_indoor.pt``), which says where the service is
    installed; a client is told the file name only, the same name ``jointseg models`` lists.
    Applied where the service hands a report out (the API and the viewer), so reports stored
    by any version of the worker are served clean.
    """
    if isinstance(body, dict):
        return {key: public_report(value) for key, value in body.items()}
    if isinstance(body, list):
        return [public_report(value) for value in body]
    if isinstance(body, str) and _server_path(body):
        return PureWindowsPath(body).name if "\\" in body else Path(body).name
    return body


def public_report_bytes(path: Path) -> bytes:
    """The report.json at ``path`` as :func:`public_report` gives it out (indented JSON)."""
    body = json.loads(path.read_text(encoding="utf-8"))
    return json.dumps(public_report(body), indent=2).encode()
