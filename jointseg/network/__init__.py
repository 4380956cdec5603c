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
    from jointseg.network.dgcnn import DGCNN
    from jointseg.network.dgcnn_params import DGCNNParams
    from jointseg.network.dgcnn_predict import DGCNNPredictor
    from jointseg.network.predict import RandLANetPredictor
    from jointseg.network.randlanet import RandLANet, RandLANetConfig
    from jointseg.network.registry import available_backends, load
    from jointseg.network.results import NetworkResult

_HOME = {
    "Backend": "jointseg.network.backends",
    "DGCNN": "jointseg.network.dgcnn",
    "DGCNNParams": "jointseg.network.dgcnn_params",
    "DGCNNPredictor": "jointseg.network.dgcnn_predict",
    "NetworkResult": "jointseg.network.results",
    "Predictor": "jointseg.network.backends",
    "RandLANet": "jointseg.network.randlanet",
    "RandLANetConfig": "jointseg.network.randlanet",
    "RandLANetPredictor": "jointseg.network.predict",
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
