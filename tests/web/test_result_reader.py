"""Reading a result file's sample and counts block by block, without reading it whole."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

import web.memory
import web.result_reader
from jointseg.exceptions import ScanFormatError
from jointseg.io import read_scan, write_scan
from jointseg.memory import can_release
from jointseg.scan import Scan
from web.result_reader import class_counts, read_sample, sample_rows
from web.scene import load_scene


def test_sample_rows_takes_one_row_from_every_run() -> None:
    assert np.array_equal(sample_rows(5, 10), np.arange(5))
    rows = sample_rows(1_003, 100)
    stride = 11  # ceil(1003 / 100)
    assert rows.size == 92 <= 100
    assert np.array_equal(rows // stride, np.arange(92))  # one row in each run of 11
    assert rows[-1] < 1_003
    assert len(set((rows % stride).tolist())) > 5  # not one fixed offset: no aliasing
    assert np.array_equal(sample_rows(1_003, 100), rows)  # seeded
    with pytest.raises(ValueError, match="budget"):
        sample_rows(10, 0)


def test_class_counts_put_every_value_outside_the_classes_with_unlabelled() -> None:
    counts = class_counts(np.array([0, 0, 12, -1, 13, 200, -7], dtype=np.int32))
    assert counts.shape == (14,)
    assert counts[0] == 2 and counts[12] == 1 and counts[13] == 4
    assert counts.sum() == 7


@pytest.mark.parametrize("budget", [1_000, 10_000])
def test_sample_is_the_files_rows_read_in_many_blocks(
    results: Path, budget: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = results / "labelled.ply"
    monkeypatch.setattr(web.result_reader, "BLOCK_BYTES", 5_000)  # ~80 records per block
    scan = read_scan(path)
    sample = read_sample(path, budget)
    rows = sample.rows
    assert sample.total == len(scan)
    assert rows.size == min(budget, len(scan))  # 4000 points: a stride of 4, or all of them
    assert np.all(np.diff(rows) > 0)
    assert np.array_equal(sample.xyz, scan.xyz[rows])
    assert scan.rgb is not None and np.array_equal(sample.rgb, scan.rgb[rows])
    assert scan.labels is not None and np.array_equal(sample.truth, scan.labels[rows])
    for got, name in (
        (sample.network, "network_label"),
        (sample.fused, "fused_label"),
        (sample.segments, "segment"),
    ):
        assert got.dtype == np.int32
        assert np.array_equal(got, scan.fields[name][rows])
    # the counts are those of every row, not of the sample
    assert np.array_equal(sample.counts["network"], class_counts(scan.fields["network_label"]))
    assert np.array_equal(sample.counts["fused"], class_counts(scan.fields["fused_label"]))
    assert np.array_equal(sample.counts["truth"], class_counts(scan.labels))


def _body(path: Path) -> tuple[list[str], bytes]:
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    return data[:end].decode("ascii").splitlines(), data[end:]


def test_big_endian_and_ascii_ply_give_the_same_sample(results: Path, tmp_path: Path) -> None:
    path = results / "labelled.ply"
    header, body = _body(path)
    names = [line.split()[2] for line in header if line.startswith("property")]
    types = [line.split()[1] for line in header if line.startswith("property")]
    codes = {"double": "f8", "float": "f4", "int": "i4", "uchar": "u1"}
    little = np.dtype([(n, "<" + codes[t]) for n, t in zip(names, types, strict=True)])
    records = np.frombuffer(body, dtype=little)
    big_endian = tmp_path / "big_endian.ply"
    big_header = "\n".join(header).replace("binary_little_endian", "binary_big_endian")
    big_endian.write_bytes(
        (big_header + "\n").encode() + records.astype(little.newbyteorder(">")).tobytes()
    )
    ascii_file = tmp_path / "ascii.ply"
    lines = [
        " ".join(
            repr(float(v)) if t in ("double", "float") else str(int(v))
            for v, t in zip(rec, types, strict=True)
        )
        for rec in records.tolist()
    ]
    ascii_header = "\n".join(header).replace("binary_little_endian", "ascii")
    ascii_file.write_text(ascii_header + "\n" + "\n".join(lines) + "\n")

    want = read_sample(path, 1_500)
    for other in (big_endian, ascii_file):
        got = read_sample(other, 1_500)
        assert np.array_equal(got.rows, want.rows)
        assert np.array_equal(got.xyz, want.xyz)
        for key in ("rgb", "network", "fused", "segments", "truth"):
            assert np.array_equal(getattr(got, key), getattr(want, key)), (other.name, key)
        for key, counts in want.counts.items():
            assert np.array_equal(got.counts[key], counts)


def test_a_truncated_file_or_one_that_is_no_result_is_refused(
    results: Path, tmp_path: Path
) -> None:
    data = (results / "labelled.ply").read_bytes()
    cut = tmp_path / "cut.ply"
    cut.write_bytes(data[:-100])
    with pytest.raises(ScanFormatError, match="truncated"):
        read_sample(cut, 1_000)
    scan = read_scan(results / "labelled.ply")
    plain = write_scan(Scan(scan.xyz, scan.rgb, scan.labels), tmp_path / "plain.ply")
    with pytest.raises(ScanFormatError, match="not a jointseg result.*network_label"):
        read_sample(plain, 1_000)


def test_load_scene_over_the_cap_shows_a_thinned_sample_with_full_counts(results: Path) -> None:
    path = results / "labelled.ply"
    scan = read_scan(path)
    data = load_scene(path, max_points=500)
    assert data.voxel is not None and 100 < data.xyz.shape[0] <= 500
    assert data.total_points == len(scan)
    assert data.counts["fused"].sum() == len(scan)
    assert np.array_equal(data.changed, data.network != data.fused)


def test_freed_memory_is_given_back_a_moment_after_asking(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    if not can_release():
        pytest.skip("no glibc malloc_trim here")
    trims: list[float] = []
    monkeypatch.setattr(web.memory, "release_memory", lambda: trims.append(time.monotonic()))
    asked = time.monotonic()
    for _ in range(3):  # close together: one trim after the last
        web.memory.release_soon(0.05)
    deadline = time.monotonic() + 5
    while not trims:
        assert time.monotonic() < deadline
        time.sleep(0.01)
    time.sleep(0.1)  # no second trim follows
    assert web.memory._due is None
    assert len(trims) == 1 and trims[0] - asked >= 0.05
