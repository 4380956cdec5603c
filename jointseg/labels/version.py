"""A labels version's deliverables: the result scan, its objects and its report, made from the
version's labels (the user's class where given, else the machine's).

Version 0 is the pipeline's own result and is never rewritten; a later version is the result
file of version 0 plus one array, ``user_label``. Everything a user downloads of a version is
made from those two by the functions here, so the CLI (``jointseg relabel``) and the job service
give the same files.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError
from jointseg.labels.edits import NO_USER_LABEL, version_labels
from jointseg.scan import Scan

#: The per-point field a version's files carry: the class the user gave, -1 where none.
USER_LABEL_FIELD = "user_label"
#: The fields a result must have to be corrected.
NEEDED_FIELDS = ("fused_label", "segment")


def check_result(scan: Scan, *, name: str) -> None:
    """Refuse a scan that is not a pipeline result.

    Raises
    ------
    ConfigError
        Naming the missing field.
    """
    for field in NEEDED_FIELDS:
        if field not in scan.fields:
            raise ConfigError(
                f"{name}: no {field} field; only a result of `jointseg segment` can be relabelled"
            )


def machine_labels(scan: Scan) -> np.ndarray:
    """The labels edits apply over: a result's ``fused_label`` (in a relabelled file, that
    file's version's labels, so relabelling it again builds on them)."""
    return np.asarray(scan.fields["fused_label"], dtype=np.int32)


def user_labels_of(scan: Scan) -> np.ndarray | None:
    """The ``user_label`` field a relabelled file carries, or None."""
    values = scan.fields.get(USER_LABEL_FIELD)
    return None if values is None else np.asarray(values, dtype=np.int16)


def version_scan(scan: Scan, user_label: np.ndarray | None, *, instances: Any = None) -> Scan:
    """The result scan of a version: ``fused_label`` holds the version's labels and
    ``user_label`` the user's classes (-1 where none); ``instance`` the version's objects when
    given.

    Parameters
    ----------
    scan : Scan
        Version 0's result (every field of ``jointseg segment``).
    user_label : ndarray of shape (N,), optional
        The version's user classes; None is version 0 with an all -1 ``user_label``.
    instances : ndarray of shape (N,), optional
        The version's object per point (:func:`version_layout`).
    """
    n = len(scan)
    user = np.full(n, NO_USER_LABEL, np.int16) if user_label is None else user_label
    fields: dict[str, np.ndarray] = {
        "fused_label": version_labels(machine_labels(scan), user).astype(np.int32),
        USER_LABEL_FIELD: user.astype(np.int16),
    }
    if instances is not None:
        fields["instance"] = np.asarray(instances, dtype=np.int32)
    return scan.with_fields(**fields)


def version_layout(scan: Scan, labels: np.ndarray, report: dict[str, Any] | None) -> Any:
    """Objects, rooms and walls of a version, from its labels in the frame the run decided.

    The run's report gives the transform to the work frame (``frame.to_work``) and the object
    settings (``params.objects``), so the version's objects are found as the run found its own;
    without a report the file's frame is taken as the work frame (z up, metres). Stray points
    (the result's ``stray`` field) belong to no object.

    Returns
    -------
    Layout
        ``instances`` per point of ``scan`` and ``report`` (a :class:`LayoutReport`).
    """
    from jointseg.objects.layout import find_layout
    from jointseg.objects.params import ObjectParams
    from jointseg.spacing import estimate_spacing

    body = report or {}
    frame = body.get("frame") or {}
    to_work = np.asarray(frame.get("to_work") or np.eye(4), dtype=np.float64)
    settings = (body.get("params") or {}).get("objects")
    params = ObjectParams.model_validate(settings) if isinstance(settings, dict) else None
    stray = scan.fields.get("stray")
    keep = np.ones(len(scan), bool) if stray is None else np.asarray(stray) == 0
    work = scan.xyz[keep] @ to_work[:3, :3].T + to_work[:3, 3]
    confidence = scan.fields.get("fused_confidence")
    layout = find_layout(
        work,
        labels[keep],
        None if confidence is None else np.asarray(confidence)[keep],
        estimate_spacing(work),
        to_user=np.linalg.inv(to_work),
        params=params,
    )
    instances = np.full(len(scan), -1, np.int32)
    instances[keep] = layout.instances
    from dataclasses import replace

    return replace(layout, instances=instances)


def version_report(
    report: dict[str, Any] | None, layout: Any, *, version: int, corrected: int
) -> dict[str, Any]:
    """The run's report for a version: its ``labels`` section (the version and how many points
    the user corrected) and the version's ``objects`` and ``rooms``."""
    from jointseg.objects.records import report_sections

    body = dict(report or {})
    body["labels"] = {"version": version, "points_corrected": corrected}
    if layout is not None:
        body.update(report_sections(layout.report))
    return body


def version_outputs(
    scan: Scan,
    user_label: np.ndarray | None,
    report: dict[str, Any] | None,
    *,
    version: int,
    objects: bool,
) -> tuple[Scan, Any, dict[str, Any]]:
    """Everything a version delivers, made once: its scan (:func:`version_scan`, with the
    version's ``instance`` when ``objects``), its layout (None unless ``objects``) and its
    report (:func:`version_report`)."""
    labelled = version_scan(scan, user_label)
    layout = None
    if objects:
        layout = version_layout(scan, labelled.fields["fused_label"], report)
        labelled = labelled.with_fields(instance=layout.instances)
    corrected = corrected_points(scan, user_label)
    body = version_report(report, layout, version=version, corrected=corrected)
    return labelled, layout, body


def corrected_points(scan: Scan, user_label: np.ndarray | None) -> int:
    """Points whose version label differs from the machine's."""
    if user_label is None:
        return 0
    base = machine_labels(scan)
    return int(np.count_nonzero(version_labels(base, user_label) != base))
