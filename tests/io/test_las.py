"""LAS/LAZ reading of files written by laspy directly, and bad LAS files."""

from __future__ import annotations

import dataclasses

import laspy
import numpy as np
import pytest

from jointseg.io import ScanFormatError, probe_scan, read_scan, write_scan


def _laspy_file(
    path,
    n=50,
    *,
    point_format=3,
    version="1.2",
    rgb16=True,
    cls=None,
    extra=None,
    intensity=True,
    seed=0,
):
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([1000.0, 2000.0, 0.0])
    if extra:
        header.add_extra_dims(
            [laspy.ExtraBytesParams(name=k, type=v.dtype) for k, v in extra.items()]
        )
    las = laspy.LasData(header)
    xyz = rng.uniform(0, 20, (n, 3)) + header.offsets
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rgb8 = rng.integers(0, 256, (n, 3))
    if header.point_format.id in (2, 3, 5, 7, 8, 10):
        scale = 257 if rgb16 else 1
        las.red, las.green, las.blue = (rgb8[:, i] * scale for i in range(3))
    if cls is not None:
        las.classification = cls
    if intensity:
        las.intensity = rng.integers(0, 65535, n)
    for k, v in (extra or {}).items():
        las[k] = v
    las.write(str(path))
    return xyz, rgb8


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_laspy_file_with_16_bit_colour(tmp_path, ext):
    cls = np.arange(50) % 13
    extra = {
        "range": np.linspace(0, 5, 50).astype(np.float32),
        "ring": (np.arange(50) % 16).astype(np.uint8),
    }
    xyz, rgb8 = _laspy_file(tmp_path / f"a{ext}", cls=cls, extra=extra)
    scan = read_scan(tmp_path / f"a{ext}")
    assert scan.source_format == ext[1:]
    np.testing.assert_allclose(scan.xyz, xyz, atol=6e-4)
    np.testing.assert_array_equal(scan.rgb, rgb8)
    np.testing.assert_array_equal(scan.labels, cls)
    assert set(scan.fields) == {"intensity", "range", "ring"}
    assert scan.fields["intensity"].dtype == np.uint16
    np.testing.assert_array_equal(scan.fields["range"], extra["range"])
    np.testing.assert_array_equal(scan.fields["ring"], extra["ring"])


def test_colour_stored_as_8_bit_in_16_bit_channels(tmp_path):
    _, rgb8 = _laspy_file(tmp_path / "a.las", rgb16=False)
    np.testing.assert_array_equal(read_scan(tmp_path / "a.las").rgb, rgb8)


def test_classification_255_and_above_12(tmp_path, caplog):
    cls = np.array([2, 255, 17, 12, 0] * 10)
    _laspy_file(tmp_path / "c.las", point_format=7, version="1.4", cls=cls)
    scan = read_scan(tmp_path / "c.las")
    np.testing.assert_array_equal(scan.labels, [2, -1, -1, 12, 0] * 10)
    np.testing.assert_array_equal(scan.fields["classification"], cls)
    assert "outside the S3DIS classes" in caplog.text


def test_only_255_gives_no_raw_field(tmp_path):
    _laspy_file(tmp_path / "c.las", point_format=7, version="1.4", cls=np.array([3, 255] * 25))
    scan = read_scan(tmp_path / "c.las")
    np.testing.assert_array_equal(scan.labels, [3, -1] * 25)
    assert "classification" not in scan.fields


def test_never_classified_gives_no_labels_and_zero_intensity_no_field(tmp_path):
    _laspy_file(tmp_path / "z.las", point_format=1, version="1.2", intensity=False)
    scan = read_scan(tmp_path / "z.las")
    assert scan.labels is None
    assert scan.rgb is None
    assert scan.fields == {}


def test_raw_classification_survives_a_round_trip(tmp_path):
    cls = np.array([2, 255, 17, 12, 0] * 10)
    _laspy_file(tmp_path / "c.las", point_format=7, version="1.4", cls=cls)
    first = read_scan(tmp_path / "c.las")
    again = read_scan(write_scan(first, tmp_path / "again.las"))
    np.testing.assert_array_equal(again.labels, first.labels)
    np.testing.assert_array_equal(again.fields["classification"], cls)


def test_all_ceiling_labels_written_by_us_are_kept(tmp_path, make_scan):
    scan = make_scan(20, fields=False)
    scan = dataclasses.replace(scan, labels=np.zeros(20, dtype=np.int32))
    back = read_scan(write_scan(scan, tmp_path / "ceiling.las"))
    np.testing.assert_array_equal(back.labels, 0)


def test_probe(tmp_path):
    _laspy_file(
        tmp_path / "p.las", n=33, cls=np.full(33, 2), extra={"ring": np.zeros(33, dtype=np.uint8)}
    )
    info = probe_scan(tmp_path / "p.las")
    assert (info.format, info.n_points, info.has_rgb, info.has_labels) == ("las", 33, True, True)
    assert "ring" in info.fields


# --- bad input -----------------------------------------------------------------------------


def test_not_a_las_file(tmp_path):
    (tmp_path / "x.las").write_text("x y z\n1 2 3\n")
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match="not a LAS/LAZ file"):
            fn(tmp_path / "x.las")


def test_empty_las(tmp_path):
    (tmp_path / "e.las").write_bytes(b"")
    with pytest.raises(ScanFormatError, match="empty"):
        read_scan(tmp_path / "e.las")


def test_truncated_header(tmp_path):
    _laspy_file(tmp_path / "a.las")
    data = (tmp_path / "a.las").read_bytes()
    (tmp_path / "a.las").write_bytes(data[:100])
    with pytest.raises(ScanFormatError, match="a.las"):
        read_scan(tmp_path / "a.las")


def test_truncated_points(tmp_path):
    _laspy_file(tmp_path / "a.las", n=50)
    data = (tmp_path / "a.las").read_bytes()
    (tmp_path / "a.las").write_bytes(data[: len(data) - 34 * 10])  # format 3 records: 34 bytes
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"truncated LAS.*50 points.*40 complete"):
            fn(tmp_path / "a.las")


def test_header_declares_fewer_points_than_stored(tmp_path):
    _laspy_file(tmp_path / "a.las", n=50)
    data = (tmp_path / "a.las").read_bytes()
    (tmp_path / "a.las").write_bytes(data + data[-34 * 5 :])
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"holds 55 points but the header declares 50"):
            fn(tmp_path / "a.las")


def test_corrupt_laz(tmp_path):
    _laspy_file(tmp_path / "a.laz", n=2000)
    data = bytearray((tmp_path / "a.laz").read_bytes())
    (tmp_path / "a.laz").write_bytes(bytes(data[: len(data) // 2]))
    with pytest.raises(ScanFormatError, match="a.laz: cannot decompress.*truncated or corrupt"):
        read_scan(tmp_path / "a.laz")


def test_max_points(tmp_path):
    _laspy_file(tmp_path / "a.las", n=50)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"50 points, more than max_points=49"):
            fn(tmp_path / "a.las", max_points=49)


def test_large_las_reads_fast(tmp_path, make_scan):
    import time

    scan = make_scan(200_000, fields=False)
    path = write_scan(scan, tmp_path / "big.las")
    start = time.perf_counter()
    back = read_scan(path)
    assert time.perf_counter() - start < 1.0
    np.testing.assert_allclose(back.xyz, scan.xyz, atol=1e-4)


def test_laz_is_compressed_on_every_core_into_one_core_s_bytes(tmp_path) -> None:
    """The LAZ writer's backend compresses chunks in parallel where lazrs can, and the file is
    the one a single-core compressor writes, byte for byte."""
    import io as _io

    from jointseg.io.formats.las.core import laz_backend
    from jointseg.synth import make_room

    assert laz_backend(False) is None
    assert laz_backend(True) is laspy.LazBackend.LazrsParallel
    path = write_scan(make_room(2, points=120_000), tmp_path / "room.laz")  # 3 LAZ chunks
    las = laspy.read(path)
    one_core = _io.BytesIO()
    las.write(one_core, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    assert one_core.getvalue() == path.read_bytes()
