"""The Scan container validates once so every stage can trust its arrays."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg import Scan, ScanFormatError


def test_scan_converts_dtypes_and_keeps_fields() -> None:
    scan = Scan(
        xyz=np.zeros((4, 3), dtype=np.float32),
        rgb=np.full((4, 3), 300.0),
        labels=np.array([0, 1, 2, -1], dtype=np.int64),
        fields={"intensity": np.arange(4, dtype=np.uint16)},
    )
    assert scan.xyz.dtype == np.float64
    assert scan.rgb is not None and scan.rgb.dtype == np.uint8 and scan.rgb.max() == 255
    assert scan.labels is not None and scan.labels.dtype == np.int32
    assert len(scan) == 4
    sub = scan.subset(np.array([True, False, True, False]))
    assert len(sub) == 2 and sub.fields["intensity"].tolist() == [0, 2]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"xyz": np.zeros((3, 2))}, r"shape \(N, 3\)"),
        ({"xyz": np.array([[0, 0, 0], [np.nan, 0, 0]])}, "point 1"),
        ({"xyz": np.zeros((3, 3)), "rgb": np.zeros((2, 3))}, "rgb"),
        ({"xyz": np.zeros((3, 3)), "labels": np.zeros(4)}, "labels"),
        ({"xyz": np.zeros((3, 3)), "fields": {"a": np.zeros(2)}}, "field 'a'"),
        ({"xyz": np.zeros((3, 3)), "fields": {"red": np.zeros(3)}}, "reserved"),
    ],
)
def test_scan_rejects_inconsistent_arrays(kwargs: dict, message: str) -> None:
    with pytest.raises(ScanFormatError, match=message):
        Scan(**kwargs)


def test_with_fields_does_not_mutate_the_original() -> None:
    scan = Scan(xyz=np.zeros((2, 3)))
    more = scan.with_fields(segment=np.array([3, 4]))
    assert "segment" in more.fields and "segment" not in scan.fields
