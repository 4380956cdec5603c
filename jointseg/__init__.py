"""jointseg: semantic segmentation of indoor 3D scans by joint optimisation of geometric
features and a neural network (Yao et al.)."""

from jointseg.exceptions import Cancelled, ConfigError, JointsegError, ScanFormatError
from jointseg.scan import Scan

__all__ = ["Cancelled", "ConfigError", "JointsegError", "Scan", "ScanFormatError"]
__version__ = "0.1.0"
