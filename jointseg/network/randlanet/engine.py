"""RandLA-Net's forward pass compiled by OpenVINO for the CPU: 1.56x faster per crop than torch
in float32, with every label kept (``bench/cpu_engines.py``).

Optional: it needs the ``openvino`` and ``onnx`` packages (``pip install jointseg[openvino]``).
The model is exported to ONNX for one input shape at a time (an export with dynamic point counts
labels wrongly: the random pooling's sizes are traced as constants), so each crop shape is
compiled once; the exports and OpenVINO's compiled blobs are kept in a cache folder, so that a
later process pays about 0.2 s instead of about 1 s. Crops of a shape beyond the first few
(scans smaller than one crop) run on torch.
"""

from __future__ import annotations

import hashlib
import importlib.util
import logging
import os
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

log = logging.getLogger(__name__)

#: Crop shapes compiled per model; others run on torch.
MAX_SHAPES = 4


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


class FlatInputs(torch.nn.Module):
    """The model with its per-layer lists as separate inputs, as ONNX wants them."""

    def __init__(self, model: torch.nn.Module, layers: int) -> None:
        super().__init__()
        self.model, self.layers = model, layers

    def forward(self, *xs: torch.Tensor) -> torch.Tensor:
        n = self.layers
        return self.model(xs[0], *[list(xs[1 + i * n : 1 + (i + 1) * n]) for i in range(4)])


class CompiledForward:
    """A callable with the model's forward signature that runs it through OpenVINO."""

    def __init__(
        self,
        model: torch.nn.Module,
        threads: int,
        folder: Path | None = None,
        *,
        strict: bool = True,
    ) -> None:
        ov = import_openvino()
        self.model = model
        self.strict = strict
        self.threads = threads
        self.folder = folder or cache_dir()
        self.folder.mkdir(parents=True, exist_ok=True)
        global _runtime_pid
        if not usable_here():
            raise RuntimeError("forked from a process that ran OpenVINO")
        self.core = ov.Core()
        _runtime_pid = os.getpid()
        self.core.set_property({"CACHE_DIR": str(self.folder / "blobs")})
        state = b"".join(t.detach().cpu().numpy().tobytes() for t in model.state_dict().values())
        # the configuration too: two models of the same weights may compute differently (an
        # adapted model's gate, jointseg.adapt), and must not share an export
        config = getattr(model, "config", None)
        if config is not None and hasattr(config, "model_dump_json"):
            state += config.model_dump_json().encode()
        self.digest = hashlib.sha1(state).hexdigest()[:16]
        #: infer request per input shape; None for a shape that failed to compile (torch runs it)
        self.compiled: dict[tuple, Any] = {}

    def __call__(
        self,
        features: torch.Tensor,
        coords: list[torch.Tensor],
        neighbours: list[torch.Tensor],
        pools: list[torch.Tensor],
        upsamples: list[torch.Tensor],
    ) -> torch.Tensor:
        flat = [features, *coords, *neighbours, *pools, *upsamples]
        key = tuple(tuple(t.shape) for t in flat)
        if key not in self.compiled and len(self.compiled) < MAX_SHAPES:
            self.compiled[key] = self._compile_or_none(flat, key)
        request = self.compiled.get(key)
        if request is None:
            return self.model(features, coords, neighbours, pools, upsamples)
        out = request.infer([t.numpy() for t in flat])[0]
        return torch.from_numpy(np.array(out))

    def _compile_or_none(self, flat: list[torch.Tensor], key: tuple) -> Any:
        """:meth:`_compile`, or None when it fails and the engine was not asked for by name
        (the default engine falls back to torch for that shape, with a warning)."""
        try:
            return self._compile(flat, key)
        except Exception as exc:  # export and compilation raise many types
            if self.strict:
                raise
            log.warning("OpenVINO could not compile crops of %s points (%s): torch runs them",
                        key[0][1], exc)  # fmt: skip
            return None

    def _compile(self, flat: list[torch.Tensor], key: tuple) -> Any:
        """The infer request of one input shape, from the cached export when there is one."""
        shape = hashlib.sha1(repr(key).encode()).hexdigest()[:12]
        path = self.folder / f"randlanet-{self.digest}-{shape}.onnx"
        if not path.is_file():
            layers = (len(flat) - 1) // 4
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            with warnings.catch_warnings():  # the TorchScript exporter, deprecated but the one
                warnings.simplefilter("ignore", DeprecationWarning)  # that needs no onnxscript
                torch.onnx.export(FlatInputs(self.model, layers).eval(), tuple(flat), str(tmp),
                                  dynamo=False, opset_version=17)  # fmt: skip
            tmp.replace(path)  # whole, or not at all: other processes read the same cache
            log.info("exported RandLA-Net for crops of %s points to %s", key[0][1], path.name)
        config = {"INFERENCE_NUM_THREADS": self.threads, "PERFORMANCE_HINT": "LATENCY",
                  "INFERENCE_PRECISION_HINT": "f32"}  # fmt: skip
        compiled = self.core.compile_model(self.core.read_model(str(path)), "CPU", config)
        return compiled.create_infer_request()
