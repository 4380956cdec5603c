"""Which length unit a scan's coordinates are in: from the file where it says so, else from the
scan's own scale.

LAS/LAZ files name their CRS's linear unit (an OGC WKT record, or GeoTIFF keys, read by
:mod:`jointseg.io.units`); E57 is metres by definition. Other files say nothing, but rooms are
much alike in height: a storey is 2-5 m from floor to ceiling wherever it was built, so the
extent along up, read in each candidate unit, tells millimetres (2 800) from centimetres (280),
feet (9) and metres (2.8).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jointseg.io.units import UNITS

#: Typical floor-to-ceiling height (m) and the range a single storey's up-extent falls in.
STOREY_M = 2.8
STOREY_RANGE_M = (1.8, 6.0)


@dataclass(frozen=True)
class UnitsDecision:
    """The unit chosen, metres per unit, how it was decided and how sure it is (0-1)."""

    unit: str
    metres: float
    how: str
    confidence: float


def units_from_scale(up_extent: float) -> UnitsDecision:
    """The unit in which ``up_extent`` (the scan's robust extent along up, in file units) is
    most like a storey; metres are preferred up to the top of :data:`STOREY_RANGE_M`."""
    if up_extent <= 0:
        return UnitsDecision("m", 1.0, "assumed (the scan has no height)", 0.0)
    lo, hi = STOREY_RANGE_M
    in_m = up_extent
    if lo <= in_m <= hi:
        margin = min(np.log(in_m / lo), np.log(hi / in_m)) / np.log(hi / lo) * 2
        return UnitsDecision(
            "m", 1.0, f"scale: {in_m:.2f} m from floor to top", float(0.5 + 0.5 * margin)
        )
    # US survey feet differ from feet by 2 ppm: only a file's CRS can tell them apart
    guesses = [u for u in UNITS if u != "us-ft"]
    best = min(guesses, key=lambda u: abs(np.log(up_extent * UNITS[u] / STOREY_M)))
    height = up_extent * UNITS[best]
    off = abs(np.log(height / STOREY_M))
    confidence = float(np.clip(1.0 - off / np.log(hi / STOREY_M), 0.0, 1.0))
    return UnitsDecision(
        best, UNITS[best], f"scale: {height:.2f} m from floor to top in {best}", confidence
    )
