"""The network stage (§2.1): RandLA-Net in plain PyTorch, whole-scan inference, training."""

from jointseg.network.predict import NetworkResult, RandLANetPredictor
from jointseg.network.randlanet import RandLANet, RandLANetConfig
from jointseg.network.registry import available_backends, load

__all__ = [
    "NetworkResult",
    "RandLANet",
    "RandLANetConfig",
    "RandLANetPredictor",
    "available_backends",
    "load",
]
