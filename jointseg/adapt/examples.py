"""A corrected result as training points for the head: the head's inputs at each grid
sub-sampled point of the scan (in the frame the pipeline worked in) and the class users gave
there."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from jointseg.adapt.features import head_inputs
from jointseg.adapt.head import Examples
from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.frame.decide import decide_frame, work_scan
from jointseg.frame.params import FrameParams
from jointseg.network.judge import crop_labeller
from jointseg.progress import CancelToken, ProgressFn
from jointseg.scan import Scan


@dataclass(frozen=True)
class ScanExamples:
    """One scan's training points and what the model card says of them."""

    examples: Examples
    points: int
    corrected_points: int
    classes: dict[str, int]
    #: The rows of the result the network saw (its strays left out) and each one's
    #: sub-sampled point: how a prediction on the examples reaches the result's points.
    rows: np.ndarray
    nearest: np.ndarray


def sub_targets(nearest: np.ndarray, user_label: np.ndarray, m: int) -> np.ndarray:
    """Each sub-sampled point's class: the commonest user class among the scan points it stands
    for, -1 where none of them was corrected. (M,) int64."""
    given = user_label >= 0
    if not given.any():
        return np.full(m, -1, np.int64)
    votes = np.bincount(
        nearest[given] * NUM_CLASSES + user_label[given].astype(np.int64),
        minlength=m * NUM_CLASSES,
    ).reshape(m, NUM_CLASSES)
    return np.where(votes.any(axis=1), votes.argmax(axis=1), -1).astype(np.int64)


def sub_groups(nearest: np.ndarray, user_label: np.ndarray, segment: np.ndarray | None,
               m: int) -> np.ndarray:  # fmt: skip
    """Each sub-sampled point's corrected segment (the segment of a corrected scan point it
    stands for), -1 where none of them was corrected or the result has no segments. (M,)."""
    out = np.full(m, -1, np.int64)
    if segment is None:
        return out
    given = np.flatnonzero(user_label >= 0)
    out[nearest[given]] = np.asarray(segment)[given]
    return out


def work_points(
    scan: Scan, predictor: Any, to_work: np.ndarray | None, params: FrameParams | None
) -> tuple[Scan, np.ndarray]:
    """The scan as the network saw it in the run (``to_work`` from the run's report; without it
    the frame is decided again, as the pipeline decides it) and the rows of ``scan`` it holds
    (the result's ``stray`` points left out)."""
    stray = scan.fields.get("stray")
    keep = np.ones(len(scan), bool) if stray is None else np.asarray(stray) == 0
    rows = np.flatnonzero(keep)
    bare = Scan(scan.xyz[rows], None if scan.rgb is None else scan.rgb[rows])
    if to_work is None:
        frame = decide_frame(bare, params or FrameParams(), judge=crop_labeller(predictor))
        # every point of the result is kept: its strays were already marked by the run
        work, _ = work_scan(bare, replace(frame, stray=np.zeros(len(bare), bool)))
        return work, rows
    xyz = bare.xyz.astype(np.float64) @ to_work[:3, :3].T + to_work[:3, 3]
    return Scan(xyz.astype(np.float32), bare.rgb), rows


def scan_examples(
    predictor: Any,
    scan: Scan,
    user_label: np.ndarray,
    *,
    to_work: np.ndarray | None = None,
    frame: FrameParams | None = None,
    seed: int = 0,
    progress: ProgressFn | None = None,
    cancel: CancelToken | None = None,
) -> ScanExamples:
    """The head's training points of one corrected result."""
    work, rows = work_points(scan, predictor, to_work, frame)
    inputs = head_inputs(predictor, work, seed=seed, progress=progress, cancel=cancel)
    labels = np.asarray(user_label)[rows]
    target = sub_targets(inputs.nearest, labels, len(inputs.features))
    segment = scan.fields.get("segment")
    group = sub_groups(inputs.nearest, labels, None if segment is None else segment[rows],
                       len(inputs.features))  # fmt: skip
    counts = np.bincount(labels[labels >= 0].astype(np.int64), minlength=NUM_CLASSES)
    return ScanExamples(
        Examples(inputs.features, target, inputs.probs, group),
        points=len(scan),
        corrected_points=int(np.count_nonzero(labels >= 0)),
        classes={CLASS_NAMES[c]: int(n) for c, n in enumerate(counts) if n},
        rows=rows,
        nearest=inputs.nearest,
    )
