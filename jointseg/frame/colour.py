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
    sample = rgb[:: max(1, len(rgb) // 200_000)].astype(np.float64)
    if float(sample.std(axis=0).max()) < CONSTANT_STD:
        return ColourDecision("constant", None)
    if not correct:
        return ColourDecision("rgb", None)
    mean = sample.mean(axis=0) + 1e-6
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


def apply_gains(rgb: np.ndarray, gains: np.ndarray) -> np.ndarray:
    """``rgb`` times ``gains`` per channel, clipped to 0-255, uint8."""
    return np.clip(rgb.astype(np.float32) * gains.astype(np.float32), 0, 255).astype(np.uint8)
