"""What a fitted model was made from: the provenance record written beside it, and the stable
JSON both files are written in.

Why: a model nobody can refit is a claim nobody can check. The record names every input by its
content (sha256 of each scan and weights file), the command, the date and the code; the model
file itself holds no date, path or command, so the same command on the same inputs writes the
same model file, byte for byte.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import subprocess
import time
from collections.abc import Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, ValidationError

from jointseg import __version__
from jointseg.exceptions import ConfigError
from jointseg.io.atomic import atomic_open

#: What a field holds when the fact was not recorded at the time (older shipped models).
UNKNOWN = "unknown"
#: The libraries whose versions can change a fit's numbers.
LIBRARIES = ("numpy", "scipy", "scikit-learn", "torch", "open3d-cpu", "open3d")


class ScanRecord(BaseModel):
    """One tuning scan: where it came from and its content hash."""

    model_config = ConfigDict(extra="forbid")

    dataset: str
    name: str
    #: the file as given, relative to the plan (None for generated rooms)
    path: str | None = None
    #: sha256 of the file's bytes, or of the generated arrays; "unknown" where not recorded
    sha256: str
    #: how the scan was made from its file or generator ("thinned to 3.3 cm", "make_room(...)")
    made: str = "as read"


class LabellerRecord(BaseModel):
    """One network the fit labelled scans with, named by its weights' content."""

    model_config = ConfigDict(extra="forbid")

    name: str
    network: str
    weights: str | None = None
    sha256: str


class CodeRecord(BaseModel):
    """The code that fitted: the package's version and git commit, and the libraries'."""

    model_config = ConfigDict(extra="forbid")

    jointseg: str
    commit: str
    python: str = UNKNOWN
    libraries: dict[str, str] = {}


class Provenance(BaseModel):
    """The record beside a fitted model (``<model>.provenance.json``)."""

    model_config = ConfigDict(extra="forbid")

    model: str
    model_sha256: str
    command: str
    date: str
    code: CodeRecord
    plan: dict[str, Any]
    scans: list[ScanRecord]
    labellers: list[LabellerRecord]
    facts: dict[str, Any] = {}
    notes: list[str] = []


def fit_record(
    plan: BaseModel,
    command: str,
    scans: list[ScanRecord],
    labellers: list[LabellerRecord],
    facts: dict[str, Any],
) -> Provenance:
    """The provenance of a fit made now from ``plan`` by ``command``; the model's name and hash
    are filled in by :func:`write_model`."""
    return Provenance(
        model="",
        model_sha256="",
        command=command,
        date=today(),
        code=code_record(),
        plan=plan.model_dump(mode="json"),
        scans=scans,
        labellers=labellers,
        facts=facts,
    )


def only_known(names: list[str], known: tuple[str, ...], what: str) -> list[str]:
    """``names`` when every one is in ``known``; else a ValueError listing the strangers (a plan
    validator's message)."""
    unknown = sorted(set(names) - set(known))
    if unknown:
        raise ValueError(f"unknown {what} {unknown}; known: {list(known)}")
    return names


def portable_path(path: str | Path) -> str:
    """``path`` as a record names it: relative to the project's root (``../shared/...`` for a
    file beside the checkout), so a provenance file holds no one machine's directories."""
    root = Path(__file__).resolve().parents[2]
    return os.path.relpath(Path(path).resolve(), root)


def provenance_path(model: Path) -> Path:
    """Where the provenance of ``model`` lies: ``vote_model.json`` ->
    ``vote_model.provenance.json``."""
    return model.with_name(f"{model.stem}.provenance.json")


def stable_json(body: Any, *, indent: int | None = None) -> str:
    """``body`` as JSON that depends only on its content: keys sorted, floats as Python writes
    them (the shortest text that reads back the same number), no NaN, a final newline."""
    separators = (",", ":") if indent is None else (",", ": ")
    text = json.dumps(body, sort_keys=True, indent=indent, separators=separators, allow_nan=False)
    return text + "\n"


def write_text(path: Path, text: str) -> None:
    """Replace ``path`` with ``text`` atomically (a reader never sees half a model)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(path) as f:
        f.write(text.encode("utf-8"))


def file_sha256(path: Path) -> str:
    """sha256 of a file's bytes."""
    from jointseg.network.digest import file_sha256 as digest

    return digest(path)


def arrays_sha256(*arrays: np.ndarray | None) -> str:
    """sha256 of arrays' dtypes, shapes and bytes (a generated scan's content)."""
    h = hashlib.sha256()
    for a in arrays:
        if a is None:
            h.update(b"none")
            continue
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def git_commit(root: Path | None = None) -> str:
    """``git describe --always --dirty --abbrev=40`` of the checkout the package runs from;
    "unknown" for an installed package (no checkout) or without git."""
    root = root or Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return UNKNOWN
    try:
        done = subprocess.run(
            ["git", "-C", str(root), "describe", "--always", "--dirty", "--abbrev=40"],
            capture_output=True,
            text=True,
            timeout=30,
            check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return UNKNOWN
    return done.stdout.strip() or UNKNOWN


def code_record() -> CodeRecord:
    """The package's version and commit and the numeric libraries' versions, now."""
    libraries = {}
    for name in LIBRARIES:
        try:
            libraries[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return CodeRecord(
        jointseg=__version__,
        commit=git_commit(),
        python=platform.python_version(),
        libraries=libraries,
    )


def today() -> str:
    """The date and time of a fit, in UTC (ISO 8601)."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def write_model(
    out: Path,
    body: Mapping[str, Any],
    provenance: Provenance,
    *,
    indent: int | None = None,
) -> Provenance:
    """Write the model ``body`` at ``out`` (stable JSON) and its provenance beside it, with
    the model's name and hash filled in; returns the record written."""
    text = stable_json(dict(body), indent=indent)
    write_text(out, text)
    record = provenance.model_copy(
        update={
            "model": out.name,
            "model_sha256": hashlib.sha256(text.encode("utf-8")).hexdigest(),
        }
    )
    write_text(provenance_path(out), stable_json(record.model_dump(mode="json"), indent=1))
    return record


def read_provenance(path: Path) -> Provenance:
    """The provenance record at ``path``, validated; a ConfigError naming the file otherwise."""
    try:
        return Provenance.model_validate_json(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"the provenance record {path} is missing") from exc
    except (OSError, ValidationError) as exc:
        raise ConfigError(f"the provenance record {path} is unreadable: {exc}") from exc
