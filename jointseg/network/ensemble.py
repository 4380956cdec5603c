"""Several networks as one: their class probabilities averaged per point.

Networks that err differently (RandLA-Net and DGCNN learned from different crops, scales and
features) make fewer errors on average; the fusion then votes with the averaged
probabilities. Each member labels the whole scan its own way (RandLA-Net's crop plan,
DGCNN's blocks), so tiled runs keep each member's own tile behaviour.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from jointseg.network.backends import Predictor
from jointseg.network.results import NetworkResult
from jointseg.progress import CancelToken, ProgressFn, check_cancel
from jointseg.scan import Scan


class EnsemblePredictor:
    """The mean of its members' probabilities; labels are its argmax."""

    def __init__(self, members: list[Predictor]) -> None:
        if not members:
            raise ValueError("an ensemble needs at least one network")
        self.members = members

    @property
    def name(self) -> str:
        """The members' backend names joined by '+'."""
        return "+".join(m.name for m in self.members)

    @property
    def card(self) -> dict[str, Any]:
        """The first member's card (it decides colour and what is reported as trained on)."""
        return self.members[0].card

    @property
    def device(self) -> torch.device:
        return self.members[0].device

    @property
    def model(self) -> torch.nn.Module:
        return self.members[0].model

    @property
    def batch_size(self) -> int:
        return self.members[0].batch_size

    def predict(
        self,
        scan: Scan,
        progress: ProgressFn | None = None,
        cancel: CancelToken | None = None,
        *,
        seed: int = 0,
    ) -> NetworkResult:
        """Every member on ``scan`` in turn, probabilities averaged; each member's time is
        reported as ``member:<name>``."""
        total: np.ndarray | None = None
        crops, timings = 0, {}
        n = len(self.members)
        for i, member in enumerate(self.members):
            check_cancel(cancel)

            def part(stage: str, fraction: float, i: int = i) -> None:
                if progress is not None:
                    progress(stage, (i + fraction) / n)

            t = time.perf_counter()
            result = member.predict(scan, part, cancel, seed=seed)
            timings[f"member:{member.name}"] = time.perf_counter() - t
            probs = result.probs.astype(np.float32)
            total = probs if total is None else total + probs
            crops += result.crops
        assert total is not None
        mean = (total / n).astype(np.float32)
        return NetworkResult(mean.argmax(axis=1).astype(np.int32), mean, crops, timings)
