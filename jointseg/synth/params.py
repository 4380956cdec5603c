"""Argument checks shared by the generators: bad values fail early with a named parameter."""

from __future__ import annotations

import math
import numbers

from jointseg.exceptions import ConfigError

MIN_POINTS = 1_000
MAX_POINTS = 50_000_000


def check_seed(seed: object) -> int:
    """A non-negative integer seed."""
    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or int(seed) < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


def check_points(points: object) -> int:
    """A point count in [1 000, 50 000 000]."""
    if isinstance(points, bool) or not isinstance(points, numbers.Integral):
        raise ConfigError(f"points must be an integer, got {points!r}")
    if not MIN_POINTS <= int(points) <= MAX_POINTS:
        raise ConfigError(f"points must be between {MIN_POINTS} and {MAX_POINTS}, got {points}")
    return int(points)


def check_yaw(yaw: object) -> float | None:
    """None or a finite angle in degrees."""
    if yaw is None:
        return None
    if isinstance(yaw, bool) or not isinstance(yaw, numbers.Real) or not math.isfinite(yaw):
        raise ConfigError(f"yaw must be a finite angle in degrees or None, got {yaw!r}")
    return float(yaw)


def check_count(name: str, value: object, lo: int, hi: int) -> int:
    """An integer in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ConfigError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    if not lo <= int(value) <= hi:
        raise ConfigError(f"{name} must be an integer in [{lo}, {hi}], got {value}")
    return int(value)
