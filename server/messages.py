"""Error messages a client sees: they name the user's file, never a path on the server.

Readers and the pipeline report errors with the path they were given, which on the service is
the stored upload (``data/jobs/<id>/upload.ply``); both the upload check and the worker put
the client's file name back before the message reaches the API.
"""

from __future__ import annotations

from pathlib import Path


def public_message(exc: BaseException, path: Path, filename: str) -> str:
    """``exc``'s message with every occurrence of ``path`` replaced by ``filename``."""
    return str(exc).replace(str(path), filename)
