"""Label fusion (§2.3): network labels refined by a vote inside each geometric segment."""

from jointseg.fusion.fuse import FusionResult, ScanTotals, fuse
from jointseg.fusion.offers import StructureHint
from jointseg.fusion.params import DEFAULT_MODE, FusionMode, FusionParams

__all__ = [
    "DEFAULT_MODE",
    "FusionMode",
    "FusionParams",
    "FusionResult",
    "ScanTotals",
    "StructureHint",
    "fuse",
]
