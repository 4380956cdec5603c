"""OpenVINO's runtime as jointseg uses it, without torch: whether it is installed, whether this
process may use it (not after a fork from one that did), its import and its cache folder.

Shared by the torch-side compiler (:mod:`jointseg.network.randlanet.engine`) and the torch-free
compiled predictor (:mod:`jointseg.network.randlanet.compiled`).
"""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path
from typing import Any


def openvino_available() -> bool:
    """Whether OpenVINO and the ONNX exporter's package are installed."""
    return all(importlib.util.find_spec(m) is not None for m in ("openvino", "onnx"))


#: The process that created an OpenVINO runtime, if any (its thread pool lives there).
_runtime_pid: int | None = None


def usable_here() -> bool:
    """Whether this process may run OpenVINO: not in a child forked from a process that already
    had a runtime (OpenVINO's thread pool does not survive a fork: such a child hangs)."""
    return _runtime_pid is None or _runtime_pid == os.getpid()


def import_openvino() -> Any:
    """``openvino``, without its model-conversion tools' telemetry.

    Why: ``import openvino`` imports ``openvino.tools.ovc``, which sends usage telemetry unless
    the user opted out, from a thread that forks a process. A fork while another thread is
    inside OpenBLAS (the geometry stage runs beside the network) leaves that thread spinning
    forever in ``exec_blas``: ``jointseg segment`` hung so. jointseg reads ONNX files with the
    runtime and never converts models, so the tools are kept out; a later explicit import of
    them by the caller still works.
    """
    if "openvino" in sys.modules:
        return sys.modules["openvino"]
    blocked = "openvino.tools.ovc" not in sys.modules
    if blocked:
        sys.modules["openvino.tools.ovc"] = None  # type: ignore[assignment]  # ImportError
    try:
        import openvino
    finally:
        if blocked and sys.modules.get("openvino.tools.ovc", 0) is None:
            del sys.modules["openvino.tools.ovc"]
    return openvino


def cache_dir() -> Path:
    """``$JOINTSEG_CACHE`` or ``~/.cache/jointseg``, its ``openvino`` folder."""
    root = os.environ.get("JOINTSEG_CACHE") or Path.home() / ".cache" / "jointseg"
    return Path(root) / "openvino"


def claim_runtime() -> None:
    """Record that this process now holds an OpenVINO runtime (its thread pool): a child
    forked from it must not use one (:func:`usable_here`)."""
    global _runtime_pid
    _runtime_pid = os.getpid()


def runtime(folder: Path) -> Any:
    """A new OpenVINO runtime of this process, its compiled blobs cached under ``folder``."""
    core = import_openvino().Core()
    claim_runtime()
    core.set_property({"CACHE_DIR": str(folder / "blobs")})
    return core


def infer_request(core: Any, export: Path, threads: int) -> Any:
    """An infer request of the ONNX export ``export``, compiled for the CPU in float32 (the
    labels torch gives; bfloat16 changed 2.7 % of them)."""
    config = {"INFERENCE_NUM_THREADS": threads, "PERFORMANCE_HINT": "LATENCY",
              "INFERENCE_PRECISION_HINT": "f32"}  # fmt: skip
    return core.compile_model(core.read_model(str(export)), "CPU", config).create_infer_request()
