"""The documentation's pictures of the viewer and the job page, and the code they show.

``bench/viewer_tour.py`` makes the pictures from today's product (a real ``jointseg serve``, a
real scan uploaded on the job page, the viewer's tools on real scans, the IFC model through
IfcOpenShell) and records beside them (:data:`RECORD`) a digest of the code they show
(:func:`code_digest`: every file of ``web/``). ``tests/docs/test_pictures.py`` fails when the
code changed since, so the documentation never shows an older viewer than the one shipped:
whoever changes ``web/`` runs the tour again.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

#: The record beside the pictures, relative to the repository's root.
RECORD = Path("docs/images/pictures.json")
#: The code the pictures show, relative to the repository's root.
CODE = Path("web")


def code_files(root: Path) -> list[Path]:
    """The files of :data:`CODE` under ``root`` (caches and compiled files apart), sorted."""
    folder = root / CODE
    return sorted(
        p
        for p in folder.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
    )


def code_digest(root: Path) -> str:
    """SHA-256 over the viewer's code: each file's path (from ``root``) and bytes."""
    digest = hashlib.sha256()
    for path in code_files(root):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def write_record(root: Path, pictures: list[Path]) -> Path:
    """Record the code's digest and the pictures made from it (paths from ``root``)."""
    body = {
        "code": CODE.as_posix(),
        "code_sha256": code_digest(root),
        "made_by": "bench/viewer_tour.py",
        "pictures": sorted(p.relative_to(root).as_posix() for p in pictures),
    }
    path = root / RECORD
    path.write_text(json.dumps(body, indent=2) + "\n", encoding="utf-8")
    return path


def read_record(root: Path) -> dict[str, object]:
    """The record as written by :func:`write_record`.

    Raises
    ------
    OSError, ValueError
        The record is missing or is not a JSON object.
    """
    body = json.loads((root / RECORD).read_text(encoding="utf-8"))
    if not isinstance(body, dict):
        raise ValueError(f"{RECORD} holds no JSON object")
    return body
