"""RandLA-Net's whole-scan inference through OpenVINO alone, without importing torch.

Why: a command-line run spent about a second of one core importing torch and reading the
weights, only to hand every crop to OpenVINO (the default engine). Once a weights file has
been compiled (by :class:`~jointseg.network.randlanet.engine.CompiledForward`, which needs
torch to export the model), its cache folder holds the export of every crop shape it met and a
manifest keyed by the file's SHA-1: the model's card and configuration, and which export serves
which input shape. A later process that finds the manifest builds the crops in numpy
(:mod:`~jointseg.network.randlanet.crop_arrays`), runs them through the cached export, and sums
the outputs exactly as :class:`~jointseg.network.randlanet.predict.RandLANetPredictor` does:
the same inputs into the same compiled model, so the same labels.

Anything this path does not cover (test-time views, a crop shape not compiled yet, a process
forked from one that ran OpenVINO, the torch model itself) goes to the torch predictor, loaded
on first need.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.network.anchored import (
    AnchoredCloud,
    CropPlan,
    plan_crops,
)
from jointseg.network.devices import cuda_possible
from jointseg.network.randlanet.config import RandLANetConfig
from jointseg.network.randlanet.crop_arrays import crop_arrays
from jointseg.network.randlanet.manifest import read_manifest, shape_key
from jointseg.network.randlanet.ov_runtime import (
    cache_dir,
    infer_request,
    openvino_available,
    runtime,
    usable_here,
)
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.randlanet.whole_scan import (
    STAGE,
    add_crop_outputs,
    crop_batches,
    predict_tile,
    predict_whole,
)
from jointseg.network.results import CellSums, NetworkResult
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

log = logging.getLogger(__name__)


def compiled_threads() -> int:
    """Threads of a forward pass: torch's where torch is loaded (a worker sets its share of
    the machine there), else every core this process may run on."""
    torch = sys.modules.get("torch")
    if torch is not None:
        from jointseg.network.randlanet.predict import forward_threads

        return forward_threads()
    return len(os.sched_getaffinity(0))


class CompiledRandLANet:
    """A RandLA-Net predictor that runs the cached OpenVINO export of its weights, in numpy.

    The torch ``model`` and ``batches`` are the torch predictor's, loaded on first use.
    """

    name = "randlanet"
    #: The work around the network runs in numpy and scipy (never on a device).
    on_device = False

    def __init__(
        self,
        weights: Path,
        manifest: dict[str, Any],
        *,
        batch_size: int,
        params: RandLANetParams,
        folder: Path,
    ) -> None:
        self.weights = weights
        self.card: dict[str, Any] = dict(manifest.get("card") or {})
        self.config = RandLANetConfig.model_validate(manifest["config"])
        self.exports: dict[str, str] = dict(manifest["shapes"])
        self.batch_size = batch_size
        self.params = params
        self.folder = folder
        self.num_points = self.config.num_points
        self.min_possibility = params.coverage
        self.threads = compiled_threads()
        self._requests: dict[str, Any] = {}
        self._request_pid = -1
        self._torch: Any = None
        self._ready: dict[int, bool] = {}
        self._ready_pid = os.getpid()

    # --- what the Predictor protocol and the pipeline read ---------------------------------
    @property
    def device(self) -> str:
        """Where the network runs: the CPU."""
        return "cpu"

    @property
    def engine(self) -> str:
        """``openvino``; in a child forked from a process that ran OpenVINO, the torch
        predictor's (``torch``), as that child runs it."""
        return "openvino" if usable_here() else str(self.torch_predictor().engine)

    @property
    def grid_size(self) -> float:
        """Side (m) of the grid the network sub-samples a scan on."""
        return float(self.params.grid or self.config.grid_size)

    def torch_predictor(self) -> Any:
        """The same weights as a torch :class:`RandLANetPredictor` (imports torch: seconds)."""
        if self._torch is None:
            from jointseg.network.randlanet.predict import load_randlanet

            log.info("network: loading %s in torch", self.weights.name)
            self._torch = load_randlanet(
                self.weights, device="cpu", batch_size=self.batch_size, params=self.params
            )
        return self._torch

    @property
    def model(self) -> Any:
        """The torch model (loaded on first use: the compiled path never needs it)."""
        return self.torch_predictor().model

    def batches(self, *args: Any, **kwargs: Any) -> Any:
        """The torch predictor's batches (tensors), for callers that feed the model."""
        return self.torch_predictor().batches(*args, **kwargs)

    # --- inference ---------------------------------------------------------------------------
    def plan(self, cloud: AnchoredCloud, seed: int) -> CropPlan:
        """The crop plan of a whole scan's sub-sample (the torch predictor's, on the CPU)."""
        return plan_crops(cloud, self.num_points, self.min_possibility, seed)

    def _request(self, flat: list[np.ndarray]) -> Any | None:
        """The infer request of these inputs' shape; None when none was compiled for it, or
        OpenVINO may not run in this process."""
        key = shape_key(flat)
        export = self.exports.get(key)
        if export is None or not usable_here():
            return None
        pid = os.getpid()
        if self._request_pid != pid:  # a fork never uses its parent's requests
            self._requests, self._request_pid = {}, pid
        if key not in self._requests:
            core = runtime(self.folder)
            self._requests[key] = infer_request(core, self.folder / export, self.threads)
        return self._requests[key]

    def prepare(self, crop_size: int | None = None) -> bool:
        """Compile the request of a crop of ``crop_size`` points (default: a full crop) ahead
        of the scan, so a run that loads the network beside its reading pays it there. False
        when this path cannot run that shape (the torch predictor will)."""
        size = crop_size or self.num_points
        fake = self._example(size)
        try:
            return self._request(fake.flat()) is not None
        except (OSError, RuntimeError) as exc:
            log.warning("OpenVINO unusable here (%s): the network runs on torch", exc)
            self.exports = {}
            return False

    def _example(self, size: int) -> Any:
        """Inputs of a crop of ``size`` points (their shapes are what matters)."""
        rng = np.random.default_rng(0)
        xyz = rng.random((size, 3), dtype=np.float32)
        crops = [(xyz, np.zeros((size, 3), np.float32), None, np.arange(size))] * self.batch_size
        return crop_arrays(crops, self.config)

    def _runs_here(self, crop_size: int) -> bool:
        if self._ready_pid != os.getpid():  # a forked child asks again (usable_here)
            self._ready, self._ready_pid = {}, os.getpid()
        if crop_size not in self._ready:
            self._ready[crop_size] = self.params.views == 1 and self.prepare(crop_size)
        return self._ready[crop_size]

    def crop_sums(
        self,
        cloud: AnchoredCloud,
        plan: CropPlan,
        crops: np.ndarray,
        *,
        seed: int,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Softmax outputs of the crops ``crops`` summed per sub-sampled point: (M, 13)
        float64 sums and (M,) counts of crops that saw each point."""
        from jointseg.network.batches import Prefetcher

        if not self._runs_here(plan.crop_size):
            return self.torch_predictor().crop_sums(  # type: ignore[no-any-return]
                cloud, plan, crops, seed=seed, progress=progress, cancel=cancel
            )
        m, classes = len(cloud.xyz), self.config.num_classes
        prob_sum = np.zeros((m, classes), dtype=np.float64)
        seen = np.zeros(m, dtype=np.float64)
        crops = np.asarray(crops, dtype=np.int64)
        source = crop_batches(cloud, plan, crops, seed, self.batch_size, self.config)
        with Prefetcher(source) as ahead:
            for arrays, done in ahead:
                check_cancel(cancel)
                flat = arrays.flat()
                request = self._request(flat)
                if request is None:
                    raise RuntimeError(f"no compiled network for inputs {shape_key(flat)}")
                add_crop_outputs(prob_sum, seen, request.infer(flat)[0], arrays.indices)
                report(progress, STAGE, 0.95 * done / max(len(crops), 1))
        return prob_sum, seen

    def predict(
        self,
        scan: Scan,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
        *,
        seed: int = 0,
    ) -> NetworkResult:
        """Label every point of ``scan`` (as :meth:`RandLANetPredictor.predict`)."""
        if len(scan) == 0:
            raise ConfigError("cannot run the network on an empty scan")
        return predict_whole(self, scan, progress, cancel, seed)

    def predict_cells(
        self,
        scan: Scan,
        plan: CropPlan,
        lower: np.ndarray,
        crops: np.ndarray,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
        *,
        seed: int = 0,
    ) -> CellSums:
        """One tile's share of a whole-scan inference (as
        :meth:`RandLANetPredictor.predict_cells`)."""
        return predict_tile(self, scan, plan, lower, crops, progress, cancel, seed)


def load_compiled(
    path: Path, *, device: str | None, batch_size: int | None, params: RandLANetParams | None
) -> CompiledRandLANet | None:
    """The torch-free predictor of the weights at ``path``, when it can serve them: on the CPU,
    OpenVINO installed and usable here, the default or OpenVINO engine, one view, and a manifest
    in the cache from an earlier compilation. None otherwise (the torch loader then runs)."""
    params = params or RandLANetParams()
    if params.engine == "torch" or params.views != 1 or not openvino_available():
        return None
    if not usable_here():
        return None
    if device is None:
        if cuda_possible():
            return None
    elif device != "cpu":
        return None
    try:
        manifest = read_manifest(path)
    except OSError:
        return None
    if manifest is None:
        return None
    try:
        return CompiledRandLANet(
            path, manifest, batch_size=batch_size or 1, params=params, folder=cache_dir()
        )
    except ValueError as exc:  # a manifest whose configuration no longer validates
        log.warning("ignoring the compiled network's manifest for %s: %s", path.name, exc)
        return None
