"""What every backend's predictor shares: the device it runs on and the network, card and batch
size it holds (RandLA-Net's and DGCNN's predictors build on :class:`NetworkPredictor`)."""

from __future__ import annotations

from typing import Any

import torch


def pick_device(device: str | None = None) -> torch.device:
    """CUDA when present (or asked for), else CPU."""
    if device:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


class NetworkPredictor:
    """What every backend's predictor holds: its network in eval mode on its device, the
    model card, and how many crops or blocks go through one forward pass."""

    name: str

    def __init__(
        self,
        model: torch.nn.Module,
        card: dict[str, Any] | None,
        *,
        device: str | None,
        batch_size: int,
    ) -> None:
        self.device = pick_device(device)
        self.model = model.to(self.device).eval()
        self.card = card or {}
        self.batch_size = batch_size
