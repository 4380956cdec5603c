"""Walls as a BIM model wants them: a thickness measured where both faces of a wall were seen,
and base lines that meet at the corners so the model closes.

A scan sees a wall as one or two faces (:class:`jointseg.objects.walls.WallFace`): two when
the rooms on both sides were scanned. Two parallel faces whose bodies point at each other, less
than :data:`MAX_THICKNESS` apart and overlapping along their length, are one wall of that
thickness; a face alone keeps the declared default (``ObjectParams.wall_thickness``), which
``objects.json`` and the IFC model both state. Faces that cross at right angles near their ends
are cut or lengthened to meet there, and each body runs on through the other wall's body, so
the outer corner is closed too; a face that ends near the middle of another (a T) runs to it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol


class WallFace(Protocol):
    """What this module reads of a face (:class:`jointseg.objects.walls.WallFace`)."""

    @property
    def axis(self) -> int: ...
    @property
    def c(self) -> float: ...
    @property
    def u0(self) -> float: ...
    @property
    def u1(self) -> float: ...
    @property
    def back(self) -> int: ...


#: Two faces of one wall are at most this far apart, m (the issue's 0.5 m) ...
MAX_THICKNESS = 0.5
#: ... and at least this far (closer faces are one face seen twice, or a skirting board).
MIN_THICKNESS = 0.05
#: ... and overlap along the wall by at least this share of the shorter one.
MIN_OVERLAP = 0.5
#: A face's end is moved onto a crossing face at most this far, m: a doorway beside a corner
#: leaves a gap about this wide; more is no corner.
JOIN = 0.6


def wall_pairs(faces: Sequence[WallFace]) -> dict[int, tuple[int, float]]:
    """The faces that are two sides of one wall: face index to (the other face, thickness m),
    each face in at most one pair, the nearest pairs taken first."""
    found: list[tuple[float, int, int]] = []
    for i, a in enumerate(faces):
        for j, b in enumerate(faces):
            if j <= i or a.axis != b.axis or a.back != -b.back:
                continue
            gap = (b.c - a.c) * a.back  # > 0: b lies on a's body side
            if not MIN_THICKNESS <= gap <= MAX_THICKNESS:
                continue
            overlap = min(a.u1, b.u1) - max(a.u0, b.u0)
            if overlap >= MIN_OVERLAP * min(a.u1 - a.u0, b.u1 - b.u0):
                found.append((gap, i, j))
    out: dict[int, tuple[int, float]] = {}
    for gap, i, j in sorted(found):
        if i not in out and j not in out:
            out[i], out[j] = (j, gap), (i, gap)
    return out


@dataclass
class Span:
    """A face's span along its wall after the corners were joined, and how far its body runs
    on beyond each end (into the crossing wall's body), with the face met at each end."""

    u0: float
    u1: float
    extend0: float = 0.0
    extend1: float = 0.0
    joined0: int | None = None
    joined1: int | None = None


def joined_spans(faces: Sequence[WallFace], thickness: Sequence[float]) -> list[Span]:
    """Each face's span with its ends moved onto the faces crossing it near them (within
    :data:`JOIN`), where the crossing face's own end is near too: the two faces then meet at
    the room's corner, and each body runs on by the other wall's thickness."""
    spans = [Span(f.u0, f.u1) for f in faces]
    for i, a in enumerate(faces):
        for j, b in enumerate(faces):
            if j <= i or a.axis == b.axis:
                continue
            # a runs along b's axis: its ends are coordinates comparable with b.c, and b's with a.c
            end_a = _near_end(spans[i], b.c)
            end_b = _near_end(spans[j], a.c)
            if end_a is not None and end_b is not None:  # an L: both run on to the corner
                _meet(spans[i], end_a, b.c, thickness[j], j)
                _meet(spans[j], end_b, a.c, thickness[i], i)
            elif end_a is not None and _inside(spans[j], a.c):  # a T: a stops at b's face
                _meet(spans[i], end_a, b.c, 0.0, j)
            elif end_b is not None and _inside(spans[i], b.c):
                _meet(spans[j], end_b, a.c, 0.0, i)
    return spans


def _inside(span: Span, at: float) -> bool:
    """Whether ``at`` lies along ``span`` away from both its ends (a wall abutting there)."""
    return span.u0 + JOIN < at < span.u1 - JOIN


def _near_end(span: Span, at: float) -> int | None:
    """Which end of ``span`` (0 or 1) lies within :data:`JOIN` of ``at``, None if neither; an
    end already joined is not moved again."""
    d0, d1 = abs(span.u0 - at), abs(span.u1 - at)
    if d0 <= d1 and d0 <= JOIN and span.joined0 is None:
        return 0
    if d1 < d0 and d1 <= JOIN and span.joined1 is None:
        return 1
    return None


def _meet(span: Span, end: int, at: float, other_thickness: float, other: int) -> None:
    if end == 0:
        if at < span.u1:
            span.u0, span.extend0, span.joined0 = at, other_thickness, other
    elif at > span.u0:
        span.u1, span.extend1, span.joined1 = at, other_thickness, other


def thicknesses(faces: Sequence[WallFace], default: float) -> tuple[list[float], list[int | None]]:
    """Each face's wall thickness (measured for a pair, else ``default``) and its pair."""
    pairs = wall_pairs(faces)
    thick = [pairs[i][1] if i in pairs else default for i in range(len(faces))]
    other = [pairs[i][0] if i in pairs else None for i in range(len(faces))]
    return thick, other


def body_side(face: WallFace) -> int:
    """+1 when the face's body lies to the left of its run from ``u0`` to ``u1`` in the plan,
    -1 when to the right (the plan's axes are a rotation of the work frame's, so the same
    holds there)."""
    # running along +u: for axis 0 (face at x = c, running along y) left is -x; for axis 1
    # (at y = c, running along x) left is +y
    left = -1 if face.axis == 0 else 1
    return 1 if face.back == left else -1


def wall_top(rooms: list[int], ceilings: dict[int, float | None], floor_z: float,
             fallback: float) -> float:  # fmt: skip
    """Where a wall ends: the highest ceiling of the rooms beside it that has one (the
    structure reading's), else ``fallback`` (the wall points' top)."""
    heights = [h for r in rooms if (h := ceilings.get(r)) is not None]
    return floor_z + max(heights) if heights else fallback
