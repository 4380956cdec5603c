"""The whole method: network and geometry, fused, scored against ground truth when present."""

from jointseg.pipeline.config import NetworkConfig, PipelineConfig
from jointseg.pipeline.outputs import OUTPUT_FIELDS, annotate, report_body
from jointseg.pipeline.run import PipelineResult, load_predictor, run

__all__ = [
    "OUTPUT_FIELDS",
    "NetworkConfig",
    "PipelineConfig",
    "PipelineResult",
    "annotate",
    "load_predictor",
    "report_body",
    "run",
]
