"""Whole-scan inference: crops chosen by the 'possibility' scheme until every sub-sampled point
is covered, softmax outputs averaged over the crops that saw a point, then back to every input
point through its own cell's sub-sampled point (or its nearest: ``RandLANetParams.projection``).

A crop adds 1 - d²/r² to the possibility of each of its points (d: distance to the crop centre,
r: the crop's radius); Open3D-ML adds the square of that, which leaves the outer half of every
crop nearly uncounted and so asks for more crops. With the linear weight a 1 M-point room
needs 50 crops instead of 69 and four real Area_6 rooms 47 instead of 61, at the same mIoU
(0.477 vs 0.474; 0.640 vs 0.640 mean over the four rooms).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch

from jointseg.exceptions import ConfigError
from jointseg.network.anchored import (
    AnchoredCloud,
    CropPlan,
    plan_crops,
)
from jointseg.network.backends import Predictor, card_summary
from jointseg.network.base import NetworkPredictor, synchronize
from jointseg.network.batches import Prefetcher
from jointseg.network.device_crops import device_plan_crops
from jointseg.network.device_grid import DeviceCloud, device_anchored_cloud
from jointseg.network.presence import drop_absent
from jointseg.network.randlanet.checkpoint import load_checkpoint
from jointseg.network.randlanet.crops import Batch
from jointseg.network.randlanet.device import DeviceBatch, add_outputs, device_batches
from jointseg.network.randlanet.engine import (
    CompiledForward,
    model_digest,
    openvino_available,
    usable_here,
)
from jointseg.network.randlanet.model import RandLANet
from jointseg.network.randlanet.params import RandLANetParams
from jointseg.network.randlanet.views import in_view
from jointseg.network.randlanet.whole_scan import (
    add_crop_outputs,
    crop_batches,
    predict_tile,
    predict_whole,
)
from jointseg.network.results import CellSums, NetworkResult
from jointseg.progress import CancelToken, ProgressFn, check_cancel, report
from jointseg.scan import Scan

log = logging.getLogger(__name__)
STAGE = "network"

#: torch's threads when this process last forked, and in a forked child its parent's.
_threads_at_fork = 0
_parent_threads: int | None = None


def _before_fork() -> None:
    global _threads_at_fork
    _threads_at_fork = torch.get_num_threads()


def _in_forked_child() -> None:
    """torch's OpenMP pool does not survive a fork: a child whose parent had used it hangs at its
    first parallel operation. The child keeps torch to one thread; OpenVINO, whose pool is made
    in the child, gets the parent's threads (:func:`forward_threads`)."""
    global _parent_threads
    _parent_threads = _threads_at_fork
    torch.set_num_threads(1)


os.register_at_fork(before=_before_fork, after_in_child=_in_forked_child)


def forward_threads() -> int:
    """Threads of an OpenVINO forward pass: torch's, or in a forked child its parent's."""
    return _parent_threads or torch.get_num_threads()


@contextmanager
def cancellable(model: torch.nn.Module, cancel: CancelToken | None) -> Iterator[None]:
    """Check ``cancel`` before every encoder and decoder layer, so a stop request interrupts a
    forward pass (seconds on CPU for a batch of large crops) instead of waiting for it."""
    if cancel is None:
        yield
        return
    layers = [m for name, m in model.named_children() if name in {"encoder", "decoder"}]
    handles = [
        layer.register_forward_pre_hook(lambda *_: check_cancel(cancel))
        for group in layers
        for layer in group.children()
    ]
    try:
        yield
    finally:
        for handle in handles:
            handle.remove()


class RandLANetPredictor(NetworkPredictor):
    """A loaded RandLA-Net and the whole-scan inference around it."""

    name = "randlanet"
    model: RandLANet

    def __init__(
        self,
        model: RandLANet,
        card: dict[str, Any] | None = None,
        *,
        device: str | None = None,
        batch_size: int = 1,
        num_points: int | None = None,
        params: RandLANetParams | None = None,
        device_path: bool | None = None,
    ) -> None:
        super().__init__(model, card, device=device, batch_size=batch_size, device_path=device_path)
        self.num_points = num_points or model.config.num_points
        self.params = params or RandLANetParams()
        self.min_possibility = self.params.coverage
        self._compiled: CompiledForward | None = None
        #: The file the model was read from (:func:`load_randlanet`), and the model's digest
        #: then: its compiled shapes are recorded for the torch-free path while it is unchanged.
        self.weights_path: Path | None = None
        self._read_digest: str | None = None
        self._compiled_pid = -1
        self._failed_pid = -1

    @property
    def engine(self) -> str:
        """What runs the forward pass: ``openvino`` on the CPU when asked for, or by default
        (``auto``) where it is installed and usable in this process; else ``torch``."""
        if self.device.type != "cpu" or self.params.engine == "torch":
            return "torch"
        if self.params.engine == "auto":
            return "openvino" if openvino_available() and self._openvino_usable() else "torch"
        if not openvino_available():
            raise ConfigError(
                "network.randlanet.engine 'openvino': install it with pip install "
                "'jointseg[openvino]' (the openvino and onnx packages)"
            )
        return "openvino"

    def _openvino_usable(self) -> bool:
        """False in a child forked from a process that ran OpenVINO, and once compiling failed
        in this process (e.g. a read-only cache folder): the default engine then falls back to
        torch instead of hanging or failing the run."""
        return usable_here() and self._failed_pid != os.getpid()

    def _forward(self) -> Callable[..., torch.Tensor]:
        if self.engine == "torch":
            return self.model
        pid = os.getpid()
        if self._compiled is None or self._compiled_pid != pid:
            # a forked child never uses its parent's compiled model: OpenVINO's thread pool does
            # not survive a fork, so each process compiles (from the shared cache) for itself
            try:
                self._compiled = CompiledForward(
                    self.model,
                    forward_threads(),
                    strict=self.params.engine == "openvino",
                    source=self._source(),
                )
            except (OSError, RuntimeError) as exc:
                if self.params.engine == "openvino":
                    raise ConfigError(f"network.randlanet.engine 'openvino': {exc}") from exc
                log.warning("OpenVINO unusable here (%s): the network runs on torch", exc)
                self._failed_pid = pid
                return self.model
            self._compiled_pid = pid
        return self._compiled

    def _source(self) -> tuple[Path, dict[str, Any], str] | None:
        """The weights file, card and read digest for :class:`CompiledForward` to record."""
        if self.weights_path is None or self._read_digest is None:
            return None
        return self.weights_path, self.card, self._read_digest

    def batches(
        self, cloud: AnchoredCloud, plan: CropPlan, crops: np.ndarray, seed: int
    ) -> Iterator[tuple[Batch, int]]:
        """Batches of the crops ``crops`` (indices into ``plan``), each with the number of
        crops done after it. Depends only on the geometry, never on the network's outputs, so
        it runs a batch ahead in a thread (:class:`Prefetcher`)."""
        for arrays, done in crop_batches(
            cloud, plan, crops, seed, self.batch_size, self.model.config
        ):
            yield Batch.from_arrays(arrays), done

    def _view_logits(
        self, batch: Batch | DeviceBatch, cancel: CancelToken | None
    ) -> Iterator[torch.Tensor]:
        """The network's logits for a batch in each test-time view (``params.views``)."""
        views = self.params.views
        for view in range(views):
            check_cancel(cancel)
            features, coords = in_view(batch.features, batch.coords, view, views)
            yield self._forward()(features, coords, batch.neighbours, batch.pools, batch.upsamples)

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
        cfg = self.model.config
        m = len(cloud.xyz)
        prob_sum = np.zeros((m, cfg.num_classes), dtype=np.float64)
        seen = np.zeros(m, dtype=np.float64)
        source = self.batches(cloud, plan, np.asarray(crops, dtype=np.int64), seed)
        with torch.inference_mode(), cancellable(self.model, cancel), Prefetcher(source) as ahead:
            for batch, done in ahead:
                batch = batch.to(self.device)
                for logits in self._view_logits(batch, cancel):
                    add_crop_outputs(prob_sum, seen, logits.float().cpu().numpy(), batch.indices)
                report(progress, STAGE, 0.95 * done / max(len(crops), 1))
        return prob_sum, seen

    def _device_crop_sums(
        self,
        cloud: DeviceCloud,
        plan: CropPlan,
        crops: np.ndarray,
        *,
        seed: int,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`crop_sums` with every step on the device; the sums stay there."""
        cfg = self.model.config
        prob_sum = torch.zeros(
            (len(cloud), cfg.num_classes), dtype=torch.float64, device=self.device
        )
        seen = torch.zeros(len(cloud), dtype=torch.float64, device=self.device)
        source = device_batches(
            cloud,
            plan,
            np.asarray(crops, dtype=np.int64),
            seed=seed,
            config=cfg,
            batch_size=self.batch_size,
        )
        with torch.inference_mode(), cancellable(self.model, cancel), Prefetcher(source) as ahead:
            for batch, done in ahead:
                for logits in self._view_logits(batch, cancel):
                    add_outputs(prob_sum, seen, batch, logits)
                report(progress, STAGE, 0.95 * done / max(len(crops), 1))
        return prob_sum, seen

    def plan(self, cloud: AnchoredCloud, seed: int) -> CropPlan:
        """The crop plan of a whole scan's sub-sample (:func:`plan_crops`; on the device when
        :attr:`on_device`, the same plan)."""
        if self.on_device:
            xyz = torch.as_tensor(cloud.xyz, device=self.device)
            return device_plan_crops(xyz, self.num_points, self.min_possibility, seed)
        return plan_crops(cloud, self.num_points, self.min_possibility, seed)

    def _predict_on_device(
        self, scan: Scan, progress: ProgressFn | None, cancel: CancelToken | None, seed: int
    ) -> NetworkResult:
        """:meth:`predict` with the sub-sample, plan, crops and projection on the device."""
        timings: dict[str, float] = {}
        t = time.perf_counter()
        torch.manual_seed(seed)
        lower = scan.xyz.min(axis=0)
        xyz = torch.as_tensor(scan.xyz, device=self.device)  # uploaded once
        cloud = device_anchored_cloud([(xyz, scan.rgb)], self.grid_size, lower, self.device)
        plan = device_plan_crops(cloud.xyz, self.num_points, self.min_possibility, seed)
        timings["subsample"] = time.perf_counter() - t
        t = time.perf_counter()
        prob_sum, seen = self._device_crop_sums(
            cloud, plan, np.arange(len(plan)), seed=seed, progress=progress, cancel=cancel
        )
        synchronize(self.device)
        timings["crops"] = time.perf_counter() - t
        t = time.perf_counter()
        sub_probs = (prob_sum / seen.clamp(min=1)[:, None]).to(torch.float32).cpu().numpy()
        sub_probs = drop_absent(sub_probs, self.params.absent_share, self.params.absent_max_cells)
        rows = cloud.rows(xyz, self.params.projection)
        probs = torch.as_tensor(sub_probs, device=self.device)[rows]
        labels = probs.argmax(dim=1).to(torch.int32).cpu().numpy()
        probs_full = probs.cpu().numpy()
        timings["project"] = time.perf_counter() - t
        report(progress, STAGE, 1.0)
        log.info(
            "network (%s): %d points, %d sub-sampled, %d crops",
            self.device,
            len(scan),
            len(cloud),
            len(plan),
        )
        return NetworkResult(labels, probs_full, len(plan), timings)

    def predict(
        self,
        scan: Scan,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
        *,
        seed: int = 0,
    ) -> NetworkResult:
        """Label every point of ``scan``.

        Memory is bounded by the crop size and the batch: the scan itself is only held as its
        grid sub-sample plus the output arrays. A tile of a big scan run through
        :meth:`predict_cells` with the whole scan's plan gives the same outputs.

        Raises
        ------
        ConfigError
            When the scan is empty.
        """
        if len(scan) == 0:
            raise ConfigError("cannot run the network on an empty scan")
        if self.on_device:
            return self._predict_on_device(scan, progress, cancel, seed)
        torch.manual_seed(seed)
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
        """One tile's share of a whole-scan inference: the crops ``crops`` of the whole scan's
        ``plan`` (those centred in the tile's core), evaluated on the tile's points.

        Parameters
        ----------
        scan : Scan
            The tile's points (its outer box).
        plan : CropPlan
            Made by :meth:`plan` on the whole scan's sub-sample.
        lower : ndarray of shape (3,)
            The whole scan's lower corner.
        crops : ndarray of int
            Indices into ``plan`` to evaluate here.

        Returns
        -------
        CellSums
            Sums per sub-sampled cell, to be added over all tiles, and the cell of every point.
        """
        torch.manual_seed(seed)
        if self.on_device:
            return self._cells_on_device(scan, plan, lower, crops, progress, cancel, seed)
        return predict_tile(self, scan, plan, lower, crops, progress, cancel, seed)

    def _cells_on_device(
        self,
        scan: Scan,
        plan: CropPlan,
        lower: np.ndarray,
        crops: np.ndarray,
        progress: ProgressFn | None,
        cancel: CancelToken | None,
        seed: int,
    ) -> CellSums:
        """:meth:`predict_cells` with every step on the device."""
        xyz = torch.as_tensor(scan.xyz, device=self.device)  # uploaded once
        cloud = device_anchored_cloud([(xyz, scan.rgb)], self.grid_size, lower, self.device)
        prob_sum, seen = self._device_crop_sums(
            cloud, plan, crops, seed=seed, progress=progress, cancel=cancel
        )
        touched = seen > 0
        point_cell = cloud.ids[cloud.rows(xyz, self.params.projection)]
        report(progress, STAGE, 1.0)
        return CellSums(
            ids=cloud.ids[touched].cpu().numpy(),
            sums=prob_sum[touched].cpu().numpy(),
            seen=seen[touched].cpu().numpy(),
            point_cell=point_cell.cpu().numpy(),
        )

    @property
    def grid_size(self) -> float:
        """Side (m) of the grid the network sub-samples a scan on."""
        return float(self.params.grid or self.model.config.grid_size)


def load_randlanet(
    path: Path, *, device: str | None, batch_size: int, params: RandLANetParams | None = None
) -> Predictor:
    """The RandLA-Net backend's loader (see :mod:`jointseg.network.randlanet.backend`): a
    :class:`RandLANetPredictor`.

    Raises
    ------
    ConfigError
        When the file is not a readable jointseg checkpoint.
    """
    model, card, _ = load_checkpoint(path)
    predictor = RandLANetPredictor(
        model, card, device=device, batch_size=batch_size, params=params or RandLANetParams()
    )
    predictor.weights_path = Path(path)
    if predictor.engine == "openvino":  # the model as read, so a changed one is not recorded
        predictor._read_digest = model_digest(model)
    return predictor


def read_randlanet_card(path: Path) -> tuple[str, str]:
    """What the checkpoint was trained on, and the rest of its card in one line."""
    card = load_checkpoint(path)[1]
    return str(card.get("data", "-")), card_summary(card)
