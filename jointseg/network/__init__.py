"""The network stage (§2.1): RandLA-Net and DGCNN in plain PyTorch, whole-scan inference,
training (RandLA-Net).

Names are imported on first use (PEP 562), so ``jointseg.network.registry``,
``jointseg.network.published`` and the backend records (what the CLI, the configuration and the
job service need) load without torch; ``from jointseg.network import load, DGCNN`` still works.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from jointseg.lazy import lazy_attributes

if TYPE_CHECKING:
    from jointseg.network.backends import Backend, Predictor
    from jointseg.network.dgcnn.model import DGCNN
    from jointseg.network.dgcnn.params import DGCNNParams
    from jointseg.network.dgcnn.predict import DGCNNPredictor
    from jointseg.network.randlanet.model import RandLANet, RandLANetConfig
    from jointseg.network.randlanet.predict import RandLANetPredictor
    from jointseg.network.registry import available_backends, load
    from jointseg.network.results import NetworkResult

_HOME = {
    "Backend": "jointseg.network.backends",
    "DGCNN": "jointseg.network.dgcnn.model",
    "DGCNNParams": "jointseg.network.dgcnn.params",
    "DGCNNPredictor": "jointseg.network.dgcnn.predict",
    "NetworkResult": "jointseg.network.results",
    "Predictor": "jointseg.network.backends",
    "RandLANet": "jointseg.network.randlanet.model",
    "RandLANetConfig": "jointseg.network.randlanet.model",
    "RandLANetPredictor": "jointseg.network.randlanet.predict",
    "available_backends": "jointseg.network.registry",
    "load": "jointseg.network.registry",
}

__all__ = [
    "Backend",
    "DGCNN",
    "DGCNNParams",
    "DGCNNPredictor",
    "NetworkResult",
    "Predictor",
    "RandLANet",
    "RandLANetConfig",
    "RandLANetPredictor",
    "available_backends",
    "load",
]


__getattr__ = lazy_attributes(__name__, _HOME)
