"""The fitted up-axis model shipped with the package (``up_model.json``), read and checked.

Why a module of its own: the geometry's logistic steps (:mod:`jointseg.frame.gravity`) and the
weighing (:mod:`jointseg.frame.weigh`) both read the file, and neither may go on without it.
An installation that lost the file (a wheel built without its package data) would otherwise
weigh the evidence on up with zeros or placeholders and turn scans by chance, silently; here a
missing or malformed file is a :class:`~jointseg.exceptions.ConfigError` naming it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError

#: The model shipped with the library: written by `jointseg fit up-axis`
#: (:mod:`jointseg.fitting.up_axis`) with its provenance beside it, declared as package data in
#: pyproject.toml.
MODEL_FILE = Path(__file__).with_name("up_model.json")


def read_up_model(path: Path = MODEL_FILE) -> Mapping[str, Any]:
    """The JSON body of the up-axis model at ``path``.

    Raises
    ------
    ConfigError
        When the file is missing (the message names it, and says the installation is
        incomplete when it is the shipped one) or is not a JSON object.
    """
    path = Path(path)
    if not path.is_file():
        incomplete = ": the jointseg installation is incomplete; reinstall jointseg"
        why = incomplete if path == MODEL_FILE else ""
        raise ConfigError(f"the up-axis model {path} is missing{why}")
    try:
        body = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"the up-axis model {path} is unreadable: {exc}") from exc
    if not isinstance(body, dict):
        raise ConfigError(f"the up-axis model {path} is not a JSON object")
    return MappingProxyType(body)


@cache
def shipped_up_model() -> Mapping[str, Any]:
    """The shipped model (:data:`MODEL_FILE`), read once per process and only when a scan's
    frame is decided, so importing the library never fails on it."""
    return read_up_model(MODEL_FILE)


def weight_vector(body: Mapping[str, Any], key: str, size: int, path: Path) -> np.ndarray:
    """``body[key]`` as a read-only vector of ``size`` numbers; a ConfigError naming ``path``
    and ``key`` when it is absent or of another length (a model fitted on other features)."""
    value = body.get(key)
    try:
        vector = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        vector = np.empty(0)
    if value is None or vector.shape != (size,) or not np.all(np.isfinite(vector)):
        raise ConfigError(
            f"the up-axis model {path}: {key!r} must be {size} finite numbers; refit it with "
            "`jointseg fit up-axis --plan fit/up_axis.json`"
        )
    vector.flags.writeable = False
    return vector
