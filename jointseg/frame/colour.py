"""Colour as the network was trained on it, and scans that have none.

The training rooms (S3DIS, ScanNet) span mean brightness of about 85-170 (of 255) and white
balances from red/green 0.92 and blue/green 1.07 (a cold ScanNet room) to 1.24 and 0.71 (warm
ones). A scan outside that is brought back to the edge of it by a gain per channel; one within
it is left untouched, so a well-exposed scan's labels do not change. A scan whose colour is
one value everywhere (an exporter's default) carries no colour at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Mean brightness outside (LOW, HIGH) is scaled to the near target.
LOW, HIGH = 80.0, 180.0
TARGET_LOW, TARGET_HIGH = 115.0, 150.0
#: Channel ratios to green outside these ranges are brought to the nearer end.
RED_RANGE = (0.85, 1.3)
BLUE_RANGE = (0.65, 1.1)
#: Spread (0-255) under which colour is taken as constant.
CONSTANT_STD = 1.0


@dataclass(frozen=True)
class ColourDecision:
    """``kind``: rgb, none or constant; ``gains`` per channel when corrected (else None)."""

    kind: str
    gains: np.ndarray | None

    @property
    def usable(self) -> bool:
        return self.kind == "rgb"


def decide_colour(rgb: np.ndarray | None, correct: bool = True) -> ColourDecision:
    """Whether the scan has colour, and the gains that bring it within the training range."""
    if rgb is None or len(rgb) == 0:
        return ColourDecision("none", None)
    sample = rgb[:: max(1, len(rgb) // 200_000)]
    moments = _moments(sample)
    if moments is None:  # not 8- or 16-bit integers: the float moments themselves
        sample = sample.astype(np.float64)
        constant = float(sample.std(axis=0).max()) < CONSTANT_STD
        mean = sample.mean(axis=0)
    else:
        constant, mean = moments
    if constant:
        return ColourDecision("constant", None)
    if not correct:
        return ColourDecision("rgb", None)
    mean = mean + 1e-6
    gains = np.ones(3)
    red, blue = mean[0] / mean[1], mean[2] / mean[1]
    gains[0] = float(np.clip(red, *RED_RANGE)) / red
    gains[2] = float(np.clip(blue, *BLUE_RANGE)) / blue
    light = float((mean * gains).mean())
    if light < LOW:
        gains *= TARGET_LOW / light
    elif light > HIGH:
        gains *= TARGET_HIGH / light
    if np.allclose(gains, 1.0):
        return ColourDecision("rgb", None)
    return ColourDecision("rgb", gains)


#: The float spread differs from the exact one by far less than this share, so only a spread
#: this near :data:`CONSTANT_STD` is measured in floats.
_MARGIN = 1e-6


def _moments(sample: np.ndarray) -> tuple[bool, np.ndarray] | None:
    """``(sample.std(axis=0).max() < CONSTANT_STD, sample.mean(axis=0))`` of integer colour,
    as the float64 computation gives them, from each channel's exact integer sums (a count
    per value): the float sums of integers are exact, so the means are the same; the spread
    is decided exactly unless it lies within a hair of the threshold, where the float
    computation decides. None for colour that is not 8- or 16-bit integers."""
    if sample.dtype not in (np.uint8, np.uint16) or sample.ndim != 2 or sample.shape[1] != 3:
        return None
    m = len(sample)
    values = np.arange(256 if sample.dtype == np.uint8 else 65536, dtype=np.int64)
    sums, squares = [], []
    for c in range(3):
        counts = np.bincount(sample[:, c], minlength=len(values))
        sums.append(int(counts @ values))
        squares.append(int(counts @ (values * values)))
    mean = np.array(sums, dtype=np.float64) / m
    # exact variance m² var = m S2 - S1²: Python integers, no overflow
    var = [(m * s2 - s1 * s1) / (m * m) for s1, s2 in zip(sums, squares, strict=True)]
    limit = CONSTANT_STD * CONSTANT_STD
    if any(v > limit * (1 + _MARGIN) for v in var):
        return False, mean
    if all(v < limit * (1 - _MARGIN) for v in var):
        return True, mean
    return float(sample.astype(np.float64).std(axis=0).max()) < CONSTANT_STD, mean


def apply_gains(rgb: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """``rgb`` times ``gains`` per channel, clipped to 0-255, uint8."""
    return np.clip(rgb.astype(np.float32) * gains.astype(np.float32), 0, 255).astype(np.uint8)
