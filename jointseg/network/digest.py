"""SHA-256 of weight files. Its own module, below ``published`` (which checks pulled weights)
and ``convert`` (which records the source it converted), so neither imports the other for it."""

from __future__ import annotations

import hashlib
from pathlib import Path

#: Bytes read at a time: weights files are tens of MB.
CHUNK = 1 << 20


def file_sha256(path: Path) -> str:
    """SHA-256 of a file, read in chunks."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        while chunk := f.read(CHUNK):
            h.update(chunk)
    return h.hexdigest()
