"""The service's bounds on what a request can carry, beyond what ``PipelineConfig`` checks.

Why: the library takes any value its maths accepts, but on a shared service a seed of -1, a
distance of 1e300, infinity or a million neighbours would be accepted and only fail (or take a
worker's memory) in the worker, as "internal error: ValueError". These are refused at
submission (422, naming the field), and a scan whose coordinates span more than a building
can is refused with a message naming the span, at upload or when the worker reads it.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from jointseg.exceptions import ConfigError, ScanFormatError
from jointseg.io import DEFAULT_MAX_INFLATION
from jointseg.io.stream import open_chunks
from jointseg.pipeline import PipelineConfig

#: Largest magnitude of any number in a config (lengths in metres, counts): far above every
#: sensible value, far below what overflows an allocation.
MAX_MAGNITUDE = 1e6
#: Fields with tighter bounds (inclusive): (lowest, highest); None leaves a side to the model.
#: ``tiles.max_points`` is bounded by the ``max_tile_points`` setting instead.
FIELD_LIMITS: dict[str, tuple[float | None, float | None]] = {
    "seed": (0, 2**32 - 1),  # numpy's and torch's seeds
    "network.batch_size": (None, 64),
    "network.dgcnn.block_size": (0.1, 100),
    "network.dgcnn.stride": (0.05, 100),
    "network.dgcnn.num_points": (None, 65_536),
    "geometry.neighbours": (None, 64),
    "geometry.ransac_iterations": (None, 100_000),
    "fusion.neighbours": (None, 64),
}
#: Fields exempt from :data:`MAX_MAGNITUDE` (bounded elsewhere).
EXEMPT = frozenset({"tiles.max_points"})


def _numbers(value: Any, where: str) -> Iterator[tuple[str, float]]:
    """Every number in a dumped config with its dotted field name (list items by index)."""
    if isinstance(value, bool):
        return
    if isinstance(value, int | float):
        yield where, value
    elif isinstance(value, dict):
        for key, item in value.items():
            yield from _numbers(item, f"{where}.{key}" if where else str(key))
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            yield from _numbers(item, f"{where}.{i}")


def check_config_limits(config: PipelineConfig) -> None:
    """Refuse numbers the service will not run with, naming the field.

    Raises
    ------
    ConfigError
        ``config.<field>: ...`` for a non-finite number, one beyond :data:`MAX_MAGNITUDE`, or
        one outside its :data:`FIELD_LIMITS`.
    """
    for field, number in _numbers(config.model_dump(mode="python"), ""):
        low, high = FIELD_LIMITS.get(field, (None, None))
        if not math.isfinite(number):
            problem = "must be a finite number"
        elif low is not None and number < low:
            problem = f"must be at least {low:g} on this service"
        elif high is not None and number > high:
            problem = f"must be at most {high:g} on this service"
        elif field not in EXEMPT and abs(number) > MAX_MAGNITUDE:
            problem = f"must lie between -{MAX_MAGNITUDE:g} and {MAX_MAGNITUDE:g}"
        else:
            continue
        raise ConfigError(f"config.{field}: {number!r} {problem}")


def span_problem(low: np.ndarray, high: np.ndarray, max_span: float) -> str | None:
    """Why coordinates from ``low`` to ``high`` (per axis) are refused, or None."""
    with np.errstate(over="ignore", invalid="ignore"):
        span = np.asarray(high, dtype=np.float64) - np.asarray(low, dtype=np.float64)
    worst = int(np.argmax(np.where(np.isfinite(span), span, np.inf)))
    if np.isfinite(span[worst]) and span[worst] <= max_span:
        return None
    return (
        f"its coordinates span {float(span[worst]):.3g} units along {'xyz'[worst]}; this "
        f"service takes scans spanning at most {max_span:,.0f} units (a building, even in "
        f"millimetres)"
    )


def check_scan_span(xyz: np.ndarray, name: str, max_span: float) -> None:
    """Refuse a read scan whose coordinates span more than ``max_span`` along an axis.

    Raises
    ------
    ScanFormatError
        Naming the file (``name``) and the span.
    """
    problem = span_problem(xyz.min(axis=0), xyz.max(axis=0), max_span)
    if problem is not None:
        raise ScanFormatError(f"{name}: {problem}")


def check_file_span(
    path: Any,
    name: str,
    max_span: float,
    max_points: int,
    *,
    max_inflation: float = DEFAULT_MAX_INFLATION,
) -> None:
    """:func:`check_scan_span` for a stored file, read chunk by chunk (bounded memory).

    Raises
    ------
    ScanFormatError
        For the span, or as the reader does.
    """
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    with open_chunks(path, max_points=max_points, max_inflation=max_inflation) as chunks:
        for chunk in chunks.chunks():
            low = np.minimum(low, chunk.xyz.min(axis=0))
            high = np.maximum(high, chunk.xyz.max(axis=0))
    problem = span_problem(low, high, max_span)
    if problem is not None:
        raise ScanFormatError(f"{name}: {problem}")
