"""Self-training data (issue 65): unlabelled scans labelled by the method itself, only where it
is sure.

The fused labels beat the network's by a few points, and the geometry's structure reading
(floor, ceiling, wall, from the planes alone) is surer still, so the pipeline's own output on
scans nobody labelled (other sensors' captures, camera frames) can teach the network what the
geometry taught the fusion. Only the confident part is kept, the rest is -1 (ignored by the
loss):

- **structure**: a point the structure reading calls floor, ceiling or wall with at least
  :attr:`PseudoRule.structure` confidence keeps that class where the fused label agrees;
- **the vote**: any other point keeps its fused label where that label holds at least
  :attr:`PseudoRule.share` of its geometric segment's fused labels and the network itself gave
  it at least :attr:`PseudoRule.prob` (so the network agrees);
- a point the reading calls structure but whose fused label says otherwise is left out: one
  of the two is wrong (on the tuning scans the reading was right on half of them);
- the vote's labels only on a scan where the structure reading found a floor
  (:attr:`PseudoRule.vote_needs_floor`): where the pipeline could not read the scan as a
  levelled room (a table top seen close, a tilted capture, a wall alone), a sure network is
  no sure label. The vote's confidence was measured on rooms the bundled network was trained
  on; on foreign scans without a floor its sure labels were visibly wrong (beams and doors on a
  window wall, chairs and sofas on a table top).

The rule was chosen on the tuning ScanNet scans and depth-camera views of the tuning rooms,
their labels hidden from the pipeline (``bench/pseudo_labels.py``; the table is in
``docs/guide/training.md``). Points are stored in the frame the pipeline worked in (z up,
metres, strays left out), as a user's file would be levelled, so training sees upright rooms.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from jointseg.classes import CLASS_NAMES, NUM_CLASSES
from jointseg.exceptions import ConfigError
from jointseg.scan import Scan

if TYPE_CHECKING:
    from jointseg.network.backends import Predictor
    from jointseg.pipeline.stages import PipelineResult

log = logging.getLogger(__name__)

#: Bump when what is kept changes (the manifest names it beside the package's version).
PSEUDO_VERSION = 1


class PseudoRule(BaseModel):
    """Which of the pipeline's labels are sure enough to train on (every threshold is a least
    value, so raising one keeps a subset)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    structure: float = Field(0.9, ge=0.0, le=1.0, description="least structure confidence")
    share: float = Field(0.9, ge=0.0, le=1.0, description="least share of the segment")
    prob: float = Field(0.9, ge=0.0, le=1.0, description="least network probability")
    vote_needs_floor: bool = Field(
        True, description="the vote's labels only where a floor was read"
    )

    def describe(self) -> str:
        """The rule in one line, for manifests and tables."""
        gate = ", on scans with a floor" if self.vote_needs_floor else ""
        return f"structure>={self.structure:g}; share>={self.share:g}, prob>={self.prob:g}{gate}"


@dataclass(frozen=True)
class Evidence:
    """What the pipeline says about each point of the work scan, as the rule weighs it."""

    fused: np.ndarray  # (N,) fused class
    prob: np.ndarray  # (N,) the network's probability for the fused class
    structure: np.ndarray  # (N,) the structure reading's class, -1 for none
    structure_confidence: np.ndarray  # (N,) how sure the reading is, 0 where none
    share: np.ndarray  # (N,) the fused class's share of the point's geometric segment
    floor: bool = True  # the structure reading found the scan's floor level

    def __len__(self) -> int:
        return len(self.fused)


def segment_share(segments: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Each point's label's share of its segment's labels (a count per segment and class)."""
    _, seg = np.unique(segments, return_inverse=True)
    seg = seg.ravel()
    key = seg.astype(np.int64) * NUM_CLASSES + np.clip(labels, 0, NUM_CLASSES - 1)
    per_class = np.bincount(key, minlength=(int(seg.max()) + 1) * NUM_CLASSES if len(seg) else 0)
    sizes = np.bincount(seg)
    return (per_class[key] / sizes[seg]).astype(np.float32)


def evidence_from(result: PipelineResult, keep: np.ndarray | None = None) -> Evidence:
    """The rule's evidence from a pipeline result, for the points ``keep`` selects (default:
    every point the frame stage did not set aside as stray)."""
    keep = ~result.stray if keep is None else keep
    fused = result.fused_labels[keep].astype(np.int64)
    probs = result.network_probs[keep]
    geo = result.geometry
    n = len(fused)
    if geo.structure is None or geo.structure_confidence is None:
        structure, confidence = np.full(n, -1, np.int64), np.zeros(n, np.float32)
    else:
        structure = geo.structure[keep].astype(np.int64)
        confidence = np.where(structure >= 0, geo.structure_confidence[keep], 0.0)
    return Evidence(
        fused=fused,
        prob=np.take_along_axis(probs, fused[:, None], axis=1)[:, 0].astype(np.float32),
        structure=structure,
        structure_confidence=confidence.astype(np.float32),
        share=segment_share(geo.segments[keep], fused),
        floor=geo.floor_z is not None,
    )


def keep_labels(ev: Evidence, rule: PseudoRule) -> np.ndarray:
    """The pseudo-labels: the fused class where the rule is sure of it, -1 elsewhere (int8)."""
    read = ev.structure >= 0
    agree = ev.fused == ev.structure
    sure_structure = read & agree & (ev.structure_confidence >= rule.structure)
    sure_vote = (agree | ~read) & (ev.share >= rule.share) & (ev.prob >= rule.prob)
    sure_vote &= ev.floor or not rule.vote_needs_floor
    return np.where(sure_structure | sure_vote, ev.fused, -1).astype(np.int8)


@dataclass(frozen=True)
class PseudoScan:
    """A scan labelled by the pipeline, in its work frame (z up, metres, strays left out)."""

    xyz: np.ndarray
    rgb: np.ndarray | None
    labels: np.ndarray  # int8, -1 where not sure
    evidence: Evidence
    up: str  # the up the frame stage decided, for the manifest

    def counts(self) -> dict[str, int]:
        """Points kept per class (by name), and ``unlabelled``."""
        kept = np.bincount(self.labels[self.labels >= 0], minlength=NUM_CLASSES)
        out = {CLASS_NAMES[i]: int(c) for i, c in enumerate(kept) if c}
        out["unlabelled"] = int((self.labels < 0).sum())
        return out


def pseudo_label(
    scan: Scan, rule: PseudoRule, predictor: Predictor, config: Any = None
) -> tuple[PseudoScan, PipelineResult]:
    """Run the pipeline (default configuration unless ``config``) on ``scan`` with any labels
    it carries hidden, and keep what ``rule`` is sure of."""
    from jointseg.frame.decide import work_scan
    from jointseg.pipeline import PipelineConfig, run

    if len(scan) == 0:
        raise ConfigError("the scan has no points: nothing to label")
    hidden = Scan(scan.xyz, scan.rgb, None, source_format=scan.source_format)
    result = run(hidden, config or PipelineConfig(), predictor=predictor)
    assert result.frame is not None  # the pipeline always decides a frame
    work, _ = work_scan(hidden, result.frame)
    ev = evidence_from(result)
    labels = keep_labels(ev, rule)
    up = result.frame.up
    told = f"{up.axis} (confidence {up.confidence:.2f}, levelled {up.tilt_degrees:.1f} deg)"
    return PseudoScan(work.xyz, work.rgb, labels, ev, told), result


def read_unlabelled(path: Path) -> Scan:
    """A scan file as the pipeline reads it, with a clear error for one it cannot use."""
    from jointseg.io import read_scan

    try:
        scan = read_scan(path)
    except (OSError, ValueError) as err:
        raise ConfigError(f"{path}: cannot read it as a scan ({err})") from err
    if len(scan) == 0:
        raise ConfigError(f"{path}: the scan has no points")
    return scan
