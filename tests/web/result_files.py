"""Result files as the service writes them, made by the real pipeline for the viewer tests.

A module of its own (not conftest) so test modules can import it by a unique name.
"""

from __future__ import annotations

import json
from pathlib import Path

from jointseg.io import write_scan
from jointseg.pipeline import PipelineConfig, annotate, report_body, run
from jointseg.scan import Scan


def write_result(folder: Path, name: str, scan: Scan, config: PipelineConfig) -> Path:
    """Run the pipeline on ``scan`` and write ``<name>.ply`` and ``<name>.report.json``."""
    result = run(scan, config)
    path = write_scan(annotate(scan, result), folder / f"{name}.ply")
    report = report_body(scan, result)
    (folder / f"{name}.report.json").write_text(json.dumps(report), encoding="utf-8")
    return path
