"""The frame stage for a scan too big to hold: decided once from a strided sample of the whole
file, then applied to every chunk as it is spilled, so the tiles see the scan z up, in metres,
with usable colour; the output is written from the input again, in the user's coordinates.

Stray points cannot be left out of a spilled scan (every point keeps its place in the tile
index), so each point outside the box of the scan's bulk is moved onto the nearest point of the
bulk's sample instead: no normalisation (the network's height reference, the geometry's
bounding-box faces) sees how far out it was, and it lands where the network has crops.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from jointseg.frame.colour import apply_gains, decide_colour
from jointseg.frame.decide import decide_frame
from jointseg.frame.params import FrameParams
from jointseg.frame.strays import find_strays
from jointseg.io.stream import open_chunks
from jointseg.labeller import LabelFn
from jointseg.scan import Scan

#: Points of the sample the decision is made on.
SAMPLE_POINTS = 400_000
#: Points of the bulk kept to move strays onto.
ANCHOR_POINTS = 200_000
#: Margin (m) around the bulk's box before a point counts as stray (points inside it are
#: pulled onto the box without being called stray).
MARGIN_M = 0.5


def sample_scan(source: Any, max_points: int) -> tuple[Scan, int]:
    """A strided sample of the file's points (with its colour and file metadata) and the
    file's point count."""
    with open_chunks(source, max_points=max_points) as chunks:
        count = chunks.count
        sample = chunks.sample(max(1, count // SAMPLE_POINTS), 1_000_000)
    return sample, count


def decide(
    source: Any,
    params: FrameParams,
    max_points: int,
    judge_for: Callable[[bool], LabelFn | None] | None = None,
) -> tuple[dict[str, Any], np.ndarray]:
    """The frame of a big scan, as JSON the tile plan keeps (see :class:`StreamFrame`), and
    the bulk's sampled points in the working frame (where strays are moved while spilling).

    ``judge_for(usable_colour)``: the network that judges the likeliest up axes on the sample
    (the colour-free one for a scan without usable colour)."""
    sample, _ = sample_scan(source, max_points)
    judge = None
    if judge_for is not None:
        judge = judge_for(decide_colour(sample.rgb, params.colour).usable)
    frame = decide_frame(sample, params.model_copy(update={"strays": False}), judge=judge)
    work = frame.to_work(sample.xyz)
    keep = ~find_strays(work) if params.strays else np.ones(len(work), dtype=bool)
    lo = work[keep].min(axis=0)
    hi = work[keep].max(axis=0)
    bulk = work[keep][:: max(1, int(keep.sum()) // ANCHOR_POINTS)]
    return {
        "report": frame.report(),
        "summary": frame.summary(),
        "box": [lo.tolist(), hi.tolist()],
        "colour": frame.colour.kind,
        "gains": None if frame.colour.gains is None else frame.colour.gains.tolist(),
    }, bulk


class StreamFrame:
    """Applies a decided frame to chunks: work coordinates, strays pulled onto the bulk's box,
    colour dropped (none or constant) or corrected."""

    def __init__(self, decided: dict[str, Any], bulk: np.ndarray | None = None) -> None:
        self.decided = decided
        self.tree = None if bulk is None or not len(bulk) else cKDTree(bulk)
        self.bulk = bulk
        matrix = np.array(decided["report"]["to_work"])
        self.linear, self.shift = matrix[:3, :3], matrix[:3, 3]
        self.identity = bool(decided["report"]["identity"])
        self.lo, self.hi = (np.array(b) for b in decided["box"])
        self.colour_usable = decided["colour"] == "rgb"
        self.gains = None if decided["gains"] is None else np.array(decided["gains"])

    def work_xyz(self, xyz: np.ndarray) -> np.ndarray:
        return xyz if self.identity else xyz @ self.linear.T + self.shift

    def stray(self, xyz: np.ndarray) -> np.ndarray:
        """(N,) bool: farther than :data:`MARGIN_M` outside the bulk's box."""
        work = self.work_xyz(xyz)
        return np.any((work < self.lo - MARGIN_M) | (work > self.hi + MARGIN_M), axis=1)

    def apply(self, chunk: Scan) -> Scan:
        work = self.work_xyz(chunk.xyz)
        out = np.any((work < self.lo) | (work > self.hi), axis=1)
        if out.any():
            work = work.copy()
            if self.tree is not None and self.bulk is not None:
                _, nearest = self.tree.query(work[out], workers=-1)
                work[out] = self.bulk[nearest]
            else:
                work[out] = np.clip(work[out], self.lo, self.hi)
        rgb = chunk.rgb if self.colour_usable else None
        if rgb is not None and self.gains is not None:
            rgb = apply_gains(rgb, self.gains)
        return Scan(work, rgb, chunk.labels, source_format=chunk.source_format)


class Tracked:
    """Chunks put into the working frame, with the file's own bounds kept on the way (the
    output is written in the file's coordinates)."""

    def __init__(self, chunks: Any, stream: StreamFrame) -> None:
        self.chunks = chunks
        self.stream = stream
        self.lower = np.full(3, np.inf)
        self.upper = np.full(3, -np.inf)

    def __iter__(self) -> Any:
        for chunk in self.chunks:
            if len(chunk):
                self.lower = np.minimum(self.lower, chunk.xyz.min(axis=0))
                self.upper = np.maximum(self.upper, chunk.xyz.max(axis=0))
            yield self.stream.apply(chunk)

    def entry(self) -> dict[str, Any]:
        """The plan's ``frame`` entry."""
        return {
            **self.stream.decided,
            "file_lower": self.lower.tolist(),
            "file_upper": self.upper.tolist(),
        }
