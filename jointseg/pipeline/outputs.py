"""What a pipeline run leaves behind: the annotated scan and a JSON-ready report.

Shared by the command line and the job service, so both write the same fields and the same
report.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jointseg.classes import CLASS_INDEX
from jointseg.geometry import GeometryResult
from jointseg.pipeline.stages import PipelineResult
from jointseg.scan import Scan

#: Per-point fields the pipeline adds to a scan, in the order they are written.
OUTPUT_FIELDS: tuple[str, ...] = (
    "network_label",
    "network_confidence",
    "segment",
    "fused_label",
    "fused_confidence",
    "stray",
    "instance",
)


def annotate(scan: Scan, result: PipelineResult) -> Scan:
    """The input scan (xyz, colour, ground truth, its own fields) plus the pipeline's fields.

    Parameters
    ----------
    scan : Scan
        The scan ``result`` was computed on.
    result : PipelineResult

    Returns
    -------
    Scan
        With fields ``network_label`` (int32), ``network_confidence`` (float32), ``segment``
        (int32), ``fused_label`` (int32), ``fused_confidence`` (float32) and ``stray`` (uint8:
        1 for a point the frame stage set aside as stray; it still has labels) and
        ``instance`` (int32: the object a point belongs to, -1 for walls, floor, ceiling and
        strays). An ``instance`` field of the input is kept as ``instance_input``.
    """
    if "instance" in scan.fields:
        fields = {k: v for k, v in scan.fields.items() if k != "instance"}
        fields["instance_input"] = scan.fields["instance"]
        scan = Scan(scan.xyz, scan.rgb, scan.labels, fields, scan.source_format, scan.meta)
    return scan.with_fields(
        network_label=result.network_labels.astype(np.int32),
        network_confidence=result.network.confidence.astype(np.float32),
        segment=result.segments.astype(np.int32),
        fused_label=result.fused_labels.astype(np.int32),
        fused_confidence=result.fused_confidence.astype(np.float32),
        stray=result.stray.astype(np.uint8),
        instance=result.instances.astype(np.int32),
    )


def structure_section(geo: GeometryResult) -> dict[str, Any] | None:
    """What the geometry read as the room's structure: its floor and ceiling levels (metres, in
    the levelled work frame) and how many points it read as each; None when switched off."""
    if geo.structure is None:
        return None
    counts = np.bincount(geo.structure[geo.structure >= 0].astype(np.int64), minlength=3)
    return {
        "floor_z": None if geo.floor_z is None else round(geo.floor_z, 4),
        "ceiling_z": None if geo.ceiling_z is None else round(geo.ceiling_z, 4),
        "points": {name: int(counts[CLASS_INDEX[name]]) for name in ("floor", "ceiling", "wall")},
    }


def report_body(
    scan: Scan, result: PipelineResult, *, extra_timings: dict[str, float] | None = None
) -> dict[str, Any]:
    """The report of one run as plain JSON types.

    Parameters
    ----------
    scan : Scan
    result : PipelineResult
    extra_timings : dict of str to float, optional
        Seconds spent around the pipeline (reading, writing); added to the stage timings and
        to ``total``.

    Returns
    -------
    dict
        ``points``, ``segments``, ``labels_changed``, ``timings_s`` (per stage and ``total``),
        ``steps_s`` (per step inside each stage), ``params`` (resolved) and ``metrics``
        (``network``, ``fused``, ``oracle``; per-class IoU and accuracy with null for absent
        classes, ``miou``, ``macc``, ``oa``), or ``metrics: null`` without ground truth.
    """
    extra = extra_timings or {}
    timings = {k: v for k, v in result.timings.items() if k != "total"}
    timings.update(extra)
    timings["total"] = result.timings["total"] + sum(extra.values())
    return {
        "points": len(scan),
        "segments": result.geometry.n_segments,
        "labels_changed": int(np.count_nonzero(result.fusion.changed)),
        "segments_split": int(result.fusion.segment_split.sum()),
        "segments_kept": int(result.fusion.segment_kept.sum()),
        "timings_s": timings,
        "steps_s": {
            "network": result.network.timings,
            "geometry": result.geometry.timings,
            "fusion": result.fusion.timings,
        },
        "params": result.params,
        "frame": None if result.frame is None else result.frame.report(),
        "structure": structure_section(result.geometry),
        **layout_sections(result),
        "metrics": None
        if result.metrics is None
        else {name: m.model_dump() for name, m in result.metrics.items()},
    }


def layout_sections(result: PipelineResult) -> dict[str, Any]:
    """The report's ``objects`` (one record per object) and ``rooms`` (rooms, walls with their
    doors and windows, the floor's height and why a section is empty) sections."""
    from jointseg.objects.records import report_sections

    return report_sections(None if result.layout is None else result.layout.report)
