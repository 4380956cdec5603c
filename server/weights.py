"""Which weights file a job may name: a published model pulled here, or a file in the weights
folders (``settings.weights_dirs`` and the folder of the bundled weights).

Why one function for the API and the worker: the API refuses anything else at submission with
one answer whatever the file system holds (no probing of the server's files), and the worker
resolves the job's value again and opens only what this returns, so a config that got into the
job table some other way, or a file swapped for a link since, still cannot make it open a file
outside those folders.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from jointseg.exceptions import ConfigError
from jointseg.network import published
from jointseg.network.backends import WEIGHTS_DIR
from server.settings import Settings

log = logging.getLogger(__name__)

#: Longest ``network.weights`` value looked at (a longer one is refused unread).
MAX_WEIGHTS_CHARS = 255
#: Names listed in the refusal at most.
LISTED = 20


def weights_roots(settings: Settings) -> list[Path]:
    """The folders a job's weights may lie in: the configured ones, then the bundled ones."""
    roots: list[Path] = []
    for folder in [*settings.weights_dirs, WEIGHTS_DIR]:
        try:
            resolved = folder.expanduser().resolve()
        except (OSError, RuntimeError):
            continue
        if resolved not in roots:
            roots.append(resolved)
    return roots


def available_weights(settings: Settings) -> list[str]:
    """What a job may name, as names (never server paths): pulled published models and the files
    at the top of the weights folders."""
    names = [name for name in published.catalogue() if published.pulled_path(name) is not None]
    roots = weights_roots(settings)
    for root in roots:
        try:
            entries = sorted(root.iterdir())
        except OSError:
            continue
        for entry in entries:
            if entry.name.startswith(".") or entry.name in names:
                continue
            try:
                target = entry.resolve()
            except (OSError, RuntimeError):
                continue
            if target.is_file() and any(target.is_relative_to(r) for r in roots):
                names.append(entry.name)
    return names


def refusal(settings: Settings) -> ConfigError:
    """The one answer to every weights value that is not allowed, whatever it names."""
    names = available_weights(settings)
    shown = ", ".join(names[:LISTED]) + (", ..." if len(names) > LISTED else "")
    return ConfigError(
        "config.network.weights: not a model of this service (`jointseg models list`) nor a "
        f"file in its weights folders; available: {shown or 'none'}"
    )


def resolve_job_weights(value: str | os.PathLike[str], settings: Settings) -> Path:
    """The file a job's ``network.weights`` names, inside the allowed folders.

    A published name (``dgcnn-s3dis-5``) gives its pulled file; a relative path is looked up in
    each weights folder in turn; an absolute one must resolve (links followed) inside one.

    Raises
    ------
    ConfigError
        :func:`refusal` for anything else, the same whether or not such a file exists; for a
        published name not pulled yet, the command that pulls it.
    """
    text = os.fspath(value)
    if len(text) > MAX_WEIGHTS_CHARS or "\x00" in text:
        raise refusal(settings)
    catalogue = published.catalogue()
    if text in catalogue:
        pulled = published.pulled_path(text)
        if pulled is None:
            raise ConfigError(
                f"config.network.weights: {text} is not pulled on this service "
                f"(`jointseg models pull {text}` on its machines)"
            )
        return pulled
    roots = weights_roots(settings)
    given = Path(text)  # never expanded: "~" is a folder name like any other
    candidates = [given] if given.is_absolute() else [root / given for root in roots]
    for candidate in candidates:
        try:
            path = candidate.resolve()
            inside = any(path.is_relative_to(root) for root in roots)
            if inside and path.is_file():
                return path
        except (OSError, RuntimeError, ValueError):
            continue
    log.info("weights refused: not a model or a file in the weights folders")
    raise refusal(settings)
