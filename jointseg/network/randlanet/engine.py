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
import logging
import os
import warnings
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch

from jointseg.network.randlanet import ov_runtime
from jointseg.network.randlanet.config import RandLANetConfig
from jointseg.network.randlanet.manifest import record_export, shape_key
from jointseg.network.randlanet.ov_runtime import cache_dir, usable_here
from jointseg.network.randlanet.ov_runtime import openvino_available as openvino_available

log = logging.getLogger(__name__)

#: Crop shapes compiled per model; others run on torch.
MAX_SHAPES = 4


def model_digest(model: torch.nn.Module) -> str:
    """What names a model's export: its weights and its configuration (two models of the same
    weights may compute differently, e.g. an adapted model's gate, :mod:`jointseg.adapt`, and
    must not share an export)."""
    state = b"".join(t.detach().cpu().numpy().tobytes() for t in model.state_dict().values())
    config = getattr(model, "config", None)
    if config is not None and hasattr(config, "model_dump_json"):
        state += config.model_dump_json().encode()
    return hashlib.sha1(state).hexdigest()[:16]


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
        source: tuple[Path, dict[str, Any], str] | None = None,
    ) -> None:
        """``source`` is (weights file, its card, :func:`model_digest` of the model as read
        from it): each shape compiled is then recorded in the file's manifest for the
        torch-free path (:mod:`jointseg.network.randlanet.compiled`), when the model is still
        the file's."""
        self.model = model
        self.strict = strict
        self.threads = threads
        self.folder = folder or cache_dir()
        self.folder.mkdir(parents=True, exist_ok=True)
        if not usable_here():
            raise RuntimeError("forked from a process that ran OpenVINO")
        self.core = ov_runtime.runtime(self.folder)
        self.digest = model_digest(model)
        self.source = source if source is not None and source[2] == self.digest else None
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
        request = ov_runtime.infer_request(self.core, path, self.threads)
        if self.source is not None:
            weights, card, _ = self.source
            model_config = cast(RandLANetConfig, self.model.config)
            record_export(weights, config=model_config, card=card, shape=shape_key(flat),
                          export=path, folder=self.folder)  # fmt: skip
        return request
