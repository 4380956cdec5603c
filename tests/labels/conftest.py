"""A pipeline-shaped result without running the pipeline: a synthetic room whose fused labels
are its ground truth and whose segments are each class's points cut into 1 m cells."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.grouping import compact_ids
from jointseg.scan import Scan
from jointseg.synth import make_room


def result_scan(seed: int, points: int) -> Scan:
    """``make_room``'s scan with the fields a result of ``jointseg segment`` has for editing."""
    room = make_room(seed, points=points)
    assert room.labels is not None
    cells = np.floor(room.xyz).astype(np.int64)
    key = ((room.labels.astype(np.int64) * 64 + cells[:, 0]) * 64 + cells[:, 1]) * 64 + cells[:, 2]
    n = len(room)
    return room.with_fields(
        segment=compact_ids(key)[1].astype(np.int32),
        fused_label=room.labels.astype(np.int32),
        fused_confidence=np.ones(n, np.float32),
        stray=np.zeros(n, np.uint8),
    )


@pytest.fixture(scope="module")
def result() -> Scan:
    return result_scan(3, 30_000)
