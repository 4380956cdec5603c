"""The whole method: network and geometry, fused, scored against ground truth when present.

Names are imported on first use (PEP 562), so configuration alone (``PipelineConfig``: the CLI,
the service's request checks) does not pull in torch and open3d. The stages live in
``jointseg.pipeline.stages``, not in a module called ``run``, so the submodule never shadows
the ``run`` function on this package. ``segment_file`` is a whole file in, a file and a report
out (the CLI and the job service); big scans go through ``pipeline/tiled/``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from jointseg.lazy import lazy_attributes
from jointseg.pipeline.config import NetworkConfig, PipelineConfig

if TYPE_CHECKING:
    from jointseg.pipeline.outputs import OUTPUT_FIELDS, annotate, report_body
    from jointseg.pipeline.segment import SegmentedFile, segment_file
    from jointseg.pipeline.stages import PipelineResult, load_predictor, run

_LAZY = {
    "OUTPUT_FIELDS": "jointseg.pipeline.outputs",
    "annotate": "jointseg.pipeline.outputs",
    "report_body": "jointseg.pipeline.outputs",
    "PipelineResult": "jointseg.pipeline.stages",
    "load_predictor": "jointseg.pipeline.stages",
    "run": "jointseg.pipeline.stages",
    "SegmentedFile": "jointseg.pipeline.segment",
    "segment_file": "jointseg.pipeline.segment",
}

__all__ = [
    "OUTPUT_FIELDS",
    "NetworkConfig",
    "PipelineConfig",
    "PipelineResult",
    "SegmentedFile",
    "annotate",
    "load_predictor",
    "report_body",
    "run",
    "segment_file",
]


__getattr__ = lazy_attributes(__name__, _LAZY)
