"""The network stage (§2.1): RandLA-Net and DGCNN in plain PyTorch, whole-scan inference,
training (RandLA-Net)."""

from jointseg.network.dgcnn import DGCNN
from jointseg.network.dgcnn_predict import DGCNNParams, DGCNNPredictor
from jointseg.network.predict import NetworkResult, RandLANetPredictor
from jointseg.network.randlanet import RandLANet, RandLANetConfig
from jointseg.network.registry import Predictor, available_backends, load

__all__ = [
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
