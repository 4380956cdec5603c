"""Package attributes imported on first use (PEP 562), and open3d without its viewer.

Why: ``jointseg.network``, ``jointseg.pipeline`` and ``jointseg.geometry`` re-export names whose
modules pull in torch or open3d; configuration, the CLI's ``--help`` and the job service only need
the light ones. A package sets ``__getattr__ = lazy_attributes(__name__, {name: module})``.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable, Mapping
from importlib import import_module
from importlib.util import find_spec, module_from_spec, spec_from_file_location
from pathlib import Path
from types import ModuleType
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


def import_open3d() -> ModuleType:
    """``open3d``, imported with its ``visualization`` package deferred to first use.

    Why: ``import open3d`` imports ``open3d.visualization``, whose Plotly/Dash viewer costs
    0.3-0.7 s on 2 cores; jointseg uses open3d's geometry only. The package is put in place as
    an empty module that runs its real code on the first attribute asked of it, so
    ``open3d.visualization.draw_geometries`` and ``import open3d.visualization`` still work.
    When open3d is already imported, or laid out otherwise, it is imported as usual.
    """
    if "open3d" in sys.modules or "open3d.visualization" in sys.modules:
        return import_module("open3d")
    spec = find_spec("open3d")
    origin = None if spec is None or spec.origin is None else Path(spec.origin)
    init = None if origin is None else origin.parent / "visualization" / "__init__.py"
    if init is None or not init.is_file():
        return import_module("open3d")
    deferred = spec_from_file_location(
        "open3d.visualization", init, submodule_search_locations=[str(init.parent)]
    )
    if deferred is None or deferred.loader is None:
        return import_module("open3d")
    package = module_from_spec(deferred)
    loader = deferred.loader
    lock = threading.Lock()

    def run_on_first_use(name: str) -> Any:
        with lock:  # once, even when two threads ask at the same time
            if package.__dict__.pop("__getattr__", None) is not None:
                loader.exec_module(package)
        return getattr(package, name)

    package.__dict__["__getattr__"] = run_on_first_use
    sys.modules["open3d.visualization"] = package
    try:
        open3d = import_module("open3d")
    except BaseException:
        sys.modules.pop("open3d.visualization", None)
        raise
    setattr(open3d, "visualization", package)  # noqa: B010 - not in its stubs
    return open3d
