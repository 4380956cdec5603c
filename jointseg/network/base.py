"""What every backend's predictor shares: the device it runs on and the network, card and batch
size it holds (RandLA-Net's and DGCNN's predictors build on :class:`NetworkPredictor`)."""

from __future__ import annotations

from typing import Any

import torch

from jointseg.exceptions import ConfigError
from jointseg.network.devices import check_device_name


def pick_device(device: str | None = None) -> torch.device:
    """CUDA when present (or asked for), else CPU.

    A device this machine cannot give fails here, with a message the user can act on, rather
    than as torch's error somewhere in the first forward pass (the CLI and a job's worker both
    pick their device through this).

    Raises
    ------
    ConfigError
        For a device other than ``cpu``, ``cuda`` or ``cuda:N``, or CUDA on a machine without
        it (or without device ``N``).
    """
    if not device:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    check_device_name(device)
    chosen = torch.device(device)
    if chosen.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(
                f"device {device!r}: this machine's torch sees no CUDA device "
                "(torch.cuda.is_available() is False); use 'cpu'"
            )
        count = torch.cuda.device_count()
        if chosen.index is not None and chosen.index >= count:
            raise ConfigError(f"device {device!r}: this machine has {count} CUDA device(s)")
    return chosen


def synchronize(device: torch.device) -> None:
    """Wait for a CUDA device's queued work, so that a stage's measured time is its own and not
    the next one's (nothing to wait for on the CPU)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


class NetworkPredictor:
    """What every backend's predictor holds: its network in eval mode on its device, the
    model card, how many crops or blocks go through one forward pass, and whether the work around
    the network runs on the device too."""

    name: str

    def __init__(
        self,
        model: torch.nn.Module,
        card: dict[str, Any] | None,
        *,
        device: str | None,
        batch_size: int,
        device_path: bool | None = None,
    ) -> None:
        self.device = pick_device(device)
        self.model = model.to(self.device).eval()
        self.card = card or {}
        self.batch_size = batch_size
        self.device_path = device_path

    @property
    def on_device(self) -> bool:
        """Whether the work around the network (sub-sampling, crops or blocks, neighbour
        searches, the projection back) runs in torch on :attr:`device`: by default on CUDA only,
        where it keeps the GPU busy; on a CPU numpy and scipy's KD-tree are faster.
        ``device_path=True`` forces it (the tests run the device code on the CPU that way)."""
        if self.device_path is not None:
            return self.device_path
        return self.device.type == "cuda"
