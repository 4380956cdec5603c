"""Result files as the service writes them, for the viewer tests: made by the real pipeline, or
(big ones) with the pipeline's fields filled in without running it.

A module of its own (not conftest) so test modules can import it by a unique name.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from jointseg.classes import NUM_CLASSES
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


def synthetic_result(scan: Scan, *, seed: int = 0) -> Scan:
    """``scan`` with the pipeline's five fields filled without running it (a network run on a
    few hundred thousand points takes too long for a test): ``segment`` one id per 0.5 m cell
    and ground-truth class, ``network_label`` the ground truth with 5 % of the points given a
    random class, ``fused_label`` the ground truth, confidences random."""
    assert scan.labels is not None
    rng = np.random.default_rng(seed)
    truth = scan.labels.astype(np.int32)
    cells = np.floor((scan.xyz - scan.xyz.min(axis=0)) / 0.5).astype(np.int64)
    side = int(cells.max()) + 1
    key = truth.astype(np.int64) + 1
    for axis in range(3):
        key = key * side + cells[:, axis]
    _, segment = np.unique(key, return_inverse=True)
    network = truth.copy()
    noise = rng.random(len(scan)) < 0.05
    network[noise] = rng.integers(0, NUM_CLASSES, int(noise.sum()))
    return scan.with_fields(
        network_label=network,
        network_confidence=rng.uniform(0.3, 1.0, len(scan)).astype(np.float32),
        segment=segment.astype(np.int32),
        fused_label=truth,
        fused_confidence=rng.uniform(0.5, 1.0, len(scan)).astype(np.float32),
    )


def with_stray_point(scan: Scan, offset: tuple[float, float, float]) -> Scan:
    """``scan`` with one more point, a copy of its first (fields and labels too) moved
    ``offset`` metres from the scan's mean: a phone scan's stray point (a reflection, a point
    seen through a window)."""
    stray = np.asarray(scan.xyz.mean(axis=0) + np.asarray(offset))[None, :]
    return Scan(
        np.concatenate([scan.xyz, stray]),
        None if scan.rgb is None else np.concatenate([scan.rgb, scan.rgb[:1]]),
        None if scan.labels is None else np.concatenate([scan.labels, scan.labels[:1]]),
        {k: np.concatenate([v, v[:1]]) for k, v in scan.fields.items()},
    )
