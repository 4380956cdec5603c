"""Small random scans built in code, for the I/O tests and their round trips."""

from __future__ import annotations

import numpy as np

from jointseg.scan import Scan


def random_scan(
    n: int = 500,
    *,
    seed: int = 0,
    rgb: bool = True,
    labels: bool = True,
    fields: bool = True,
    extent: float = 10.0,
) -> Scan:
    """A small random scan with colour, labels (including -1) and fields of several dtypes."""
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-extent / 2, extent / 2, (n, 3)) + np.array([100.0, -50.0, 2.0])
    lab = rng.integers(-1, 13, n).astype(np.int32) if labels else None
    if labels:
        lab[:2] = (-1, 12)
    extra = {}
    if fields:
        extra = {
            "intensity": rng.random(n).astype(np.float32),
            "segment": rng.integers(-5, 1000, n).astype(np.int32),
            "count16": rng.integers(0, 65535, n).astype(np.uint16),
            "score": rng.normal(size=n),
            "tiny": rng.integers(-128, 127, n).astype(np.int8),
        }
    return Scan(
        xyz=xyz,
        rgb=rng.integers(0, 256, (n, 3)).astype(np.uint8) if rgb else None,
        labels=lab,
        fields=extra,
    )
