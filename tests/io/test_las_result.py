"""A result written as LAS/LAZ, read the way LAS tools read it (laspy, and the raw VLR bytes as
the LAS 1.4 specification lays them out): the fused class in ``classification`` as 64 + class,
the class names in the Classification Lookup VLR, the input's own classification kept in
``input_classification``; and jointseg reading such a file back."""

from __future__ import annotations

import logging
import struct
from pathlib import Path

import laspy
import numpy as np
import pytest

from jointseg.classes import CLASS_NAMES
from jointseg.io import ScanFormatError, probe_scan, read_scan, write_scan
from jointseg.io.formats.las.result import check_full_byte, result_classification
from jointseg.io.stream import open_chunks
from jointseg.scan import Scan
from tests.support.scans import random_scan

RESULT_FIELDS = ("network_label", "segment", "fused_label", "fused_confidence", "stray", "instance")
NAMES = {1: "unclassified", **{64 + i: name for i, name in enumerate(CLASS_NAMES)}}


def _result(scan: Scan, seed: int = 1) -> Scan:
    """``scan`` with the fields a pipeline run adds; some points stray."""
    rng = np.random.default_rng(seed)
    n = len(scan)
    fused = rng.integers(0, 13, n).astype(np.int32)
    return scan.with_fields(
        network_label=rng.integers(0, 13, n).astype(np.int32),
        segment=rng.integers(0, 50, n).astype(np.int32),
        fused_label=fused,
        fused_confidence=rng.random(n).astype(np.float32),
        stray=(np.arange(n) % 37 == 5).astype(np.uint8),
        instance=np.where(fused >= 5, rng.integers(0, 9, n), -1).astype(np.int32),
    )


def labels_of(scan: Scan) -> np.ndarray | None:
    """The input classification a result keeps: its labels, -1 as 255."""
    return None if scan.labels is None else np.where(scan.labels < 0, 255, scan.labels)


def _raw_vlrs(path: Path) -> dict[tuple[str, int], bytes]:
    """The VLRs of a LAS/LAZ file from its bytes: (user id, record id) to the record's data."""
    data = path.read_bytes()
    header_size, _, count = struct.unpack_from("<HII", data, 94)
    out, at = {}, header_size
    for _ in range(count):
        user, record, length = struct.unpack_from("<16sHH", data, at + 2)
        out[(user.rstrip(b"\0").decode(), record)] = data[at + 54 : at + 54 + length]
        at += 54 + length
    return out


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_classification_holds_64_plus_the_fused_class(tmp_path: Path, ext: str) -> None:
    scan = _result(random_scan(600, seed=3))
    las = laspy.read(write_scan(scan, tmp_path / f"result{ext}"))
    assert str(las.header.version) == "1.4" and las.header.point_format.id == 7
    stray = scan.fields["stray"] == 1
    assert stray.any()
    want = np.where(stray, 1, 64 + scan.fields["fused_label"])
    np.testing.assert_array_equal(las.classification, want)
    assert set(np.unique(las.classification).tolist()) <= set(NAMES)
    assert labels_of(scan) is not None
    np.testing.assert_array_equal(las["input_classification"], labels_of(scan))
    for name in RESULT_FIELDS:  # the results stay named extra dimensions
        np.testing.assert_array_equal(las[name], scan.fields[name])


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_the_lookup_vlr_names_every_class(tmp_path: Path, ext: str) -> None:
    path = write_scan(_result(random_scan(300, seed=4)), tmp_path / f"result{ext}")
    (lookup,) = laspy.read(path).header.vlrs.get("ClassificationLookupVlr")
    assert lookup.lookups == NAMES
    data = _raw_vlrs(path)[("LASF_Spec", 0)]
    entries = [data[k : k + 16] for k in range(0, len(data), 16)]
    assert len(data) == 16 * len(NAMES)
    assert {e[0]: e[1:].rstrip(b"\0").decode("ascii") for e in entries} == NAMES


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_a_result_read_back_has_the_inputs_labels_not_the_result(tmp_path, ext, caplog) -> None:
    scan = _result(random_scan(500, seed=5))
    path = write_scan(scan, tmp_path / f"result{ext}")
    with caplog.at_level(logging.INFO, logger="jointseg.io.formats.las.core"):
        back = read_scan(path)
    assert back.labels is not None
    np.testing.assert_array_equal(back.labels, scan.labels)
    assert "input_classification" not in back.fields and "classification" not in back.fields
    for name in RESULT_FIELDS:
        np.testing.assert_array_equal(back.fields[name], scan.fields[name])
    assert "labels are read from input_classification" in caplog.text
    info = probe_scan(path)
    assert info.has_labels and "input_classification" not in info.fields
    assert "fused_label" in info.fields


def test_an_odd_input_classification_survives_a_result(tmp_path: Path) -> None:
    """A LAS input whose classification holds 17 (no S3DIS class): kept as it was, and read back
    as the input was read (labels, and the raw classification field)."""
    cls = np.array([2, 255, 17, 12, 0] * 20, dtype=np.uint8)
    header = laspy.LasHeader(point_format=6, version="1.4")
    las = laspy.LasData(header)
    rng = np.random.default_rng(0)
    las.x, las.y, las.z = rng.uniform(0, 5, (3, 100))
    las.classification = cls
    las.write(str(tmp_path / "input.las"))
    first = read_scan(tmp_path / "input.las")
    path = write_scan(_result(first), tmp_path / "result.laz")
    np.testing.assert_array_equal(laspy.read(path)["input_classification"], cls)
    back = read_scan(path)
    assert first.labels is not None and back.labels is not None
    np.testing.assert_array_equal(back.labels, first.labels)
    np.testing.assert_array_equal(back.fields["classification"], cls)
    with open_chunks(path) as source:  # chunk by chunk: the same whole-file decision
        chunks = list(source.chunks(30))
    np.testing.assert_array_equal(np.concatenate([c.labels for c in chunks]), first.labels)
    raw = np.concatenate([c.fields["classification"] for c in chunks])
    np.testing.assert_array_equal(raw, cls)


def test_an_unlabelled_result_is_read_back_unlabelled(tmp_path: Path, caplog) -> None:
    scan = _result(random_scan(400, seed=6, labels=False))
    path = write_scan(scan, tmp_path / "result.las")
    las = laspy.read(path)
    assert "input_classification" not in las.point_format.extra_dimension_names
    assert (las.classification >= 64).sum() > 300  # the result, which is no ground truth
    with caplog.at_level(logging.INFO, logger="jointseg.io.formats.las.core"):
        back = read_scan(path)
    assert back.labels is None and "classification" not in back.fields
    assert "read unlabelled" in caplog.text
    assert not probe_scan(path).has_labels


def test_unclassified_and_strays_are_class_1() -> None:
    path = Path("r.las")
    fused = np.array([-1, 0, 12, 6, 6])
    got = result_classification(fused, np.array([0, 0, 0, 1, 0]), path=path)
    np.testing.assert_array_equal(got, [1, 64, 76, 1, 70])
    assert got.dtype == np.uint8


def test_bad_results_get_a_specific_error(tmp_path: Path) -> None:
    scan = _result(random_scan(100, seed=7))
    fused = scan.fields["fused_label"].copy()
    fused[[3, 9]] = 13
    with pytest.raises(ScanFormatError, match=r"'fused_label' holds 13 \(2 such points\)"):
        write_scan(scan.with_fields(fused_label=fused), tmp_path / "bad.las")
    assert not (tmp_path / "bad.las").exists()
    mine = scan.with_fields(input_classification=np.zeros(100, dtype=np.uint8))
    with pytest.raises(ScanFormatError, match="field 'input_classification' besides its labels"):
        write_scan(mine, tmp_path / "mine.laz")
    with pytest.raises(ScanFormatError, match="point format 3 holds classes 0..31 only"):
        check_full_byte(3, tmp_path / "old.las")
