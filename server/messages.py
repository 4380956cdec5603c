"""Error messages and reports a client sees: they name the user's file, never a path on the server.

Readers and the pipeline report errors with the path they were given, which on the service is
the stored upload (``data/jobs/<id>/upload.ply``); both the upload check and the worker put
the client's file name back before the message reaches the API.
"""

from __future__ import annotations

import json
from pathlib import Path, PureWindowsPath
from typing import Any


def public_message(exc: BaseException, path: Path, filename: str) -> str:
    """``exc``'s message with every occurrence of ``path`` replaced by ``filename``."""
    return str(exc).replace(str(path), filename)


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
