"""Hand-made class probability rows, for the tests of the votes that read them."""

from __future__ import annotations

import numpy as np

from jointseg.classes import NUM_CLASSES


def probs_for(rows: list[dict[int, float]]) -> np.ndarray:
    """Probability rows from {class: p}; the rest of the mass spread evenly."""
    out = np.zeros((len(rows), NUM_CLASSES), dtype=np.float32)
    for i, row in enumerate(rows):
        rest = (1.0 - sum(row.values())) / (NUM_CLASSES - len(row))
        out[i] = rest
        for c, p in row.items():
            out[i, c] = p
    return out
