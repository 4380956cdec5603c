"""Package attributes imported on first use (PEP 562).

Why: ``jointseg.network``, ``jointseg.pipeline`` and ``jointseg.geometry`` re-export names whose
modules pull in torch or open3d; configuration, the CLI's ``--help`` and the job service only need
the light ones. A package sets ``__getattr__ = lazy_attributes(__name__, {name: module})``.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Mapping
from importlib import import_module
from typing import Any


def lazy_attributes(package: str, homes: Mapping[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` for ``package`` that imports ``homes[name]`` when ``name`` is
    first asked for and keeps the value on the package, so later lookups are plain."""
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str) -> Any:
        if name not in homes:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(import_module(homes[name]), name)
        namespace[name] = value
        return value

    return __getattr__
