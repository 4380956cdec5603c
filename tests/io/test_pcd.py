"""PCD reading (ascii, binary, binary_compressed), organised clouds and bad PCD files."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from jointseg.io import ScanFormatError, probe_scan, read_scan
from jointseg.io.formats.pcd import lzf


def _header(fields, sizes, types, counts, width, height=1, points=None, data="ascii"):
    points = width * height if points is None else points
    return (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(fields)}\nSIZE {' '.join(map(str, sizes))}\n"
        f"TYPE {' '.join(types)}\nCOUNT {' '.join(map(str, counts))}\n"
        f"WIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\n"
        f"DATA {data}\n"
    )


def _packed(rgb):
    rgb = np.asarray(rgb, dtype=np.uint32)
    return (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]


def test_ascii_by_hand(tmp_path):
    rgb = np.array([[255, 0, 0], [0, 128, 0], [1, 2, 3]])
    packed = _packed(rgb)
    rows = [f"{i}.5 {i} -{i} {p} {i % 13} 0.25" for i, p in enumerate(packed)]
    text = (
        _header(
            ["x", "y", "z", "rgb", "label", "curvature"],
            [4, 4, 4, 4, 4, 4],
            ["F", "F", "F", "U", "I", "F"],
            [1] * 6,
            3,
        )
        + "\n".join(rows)
        + "\n"
    )
    (tmp_path / "a.pcd").write_text(text)
    scan = read_scan(tmp_path / "a.pcd")
    np.testing.assert_array_equal(scan.xyz[:, 0], [0.5, 1.5, 2.5])
    np.testing.assert_array_equal(scan.rgb, rgb)
    np.testing.assert_array_equal(scan.labels, [0, 1, 2])
    assert scan.fields["curvature"].dtype == np.float32
    info = probe_scan(tmp_path / "a.pcd")
    assert (info.n_points, info.has_rgb, info.has_labels, info.fields) == (
        3,
        True,
        True,
        ("curvature",),
    )


def _binary_pcd(path, n=20, *, height=1, data="binary", nan_at=(), rgb_type="F"):
    rng = np.random.default_rng(0)
    dtype = np.dtype(
        [
            ("x", "<f4"),
            ("y", "<f4"),
            ("z", "<f4"),
            ("rgb", "<f4" if rgb_type == "F" else "<u4"),
            ("normal", "<f4", (3,)),
            ("_", "u1", (4,)),
        ]
    )
    rec = np.zeros(n * height, dtype=dtype)
    for a in "xyz":
        rec[a] = rng.random(n * height)
    rgb = rng.integers(0, 256, (n * height, 3))
    bits = _packed(rgb)
    rec["rgb"] = bits.view(np.float32) if rgb_type == "F" else bits
    rec["normal"] = rng.random((n * height, 3))
    for i in nan_at:
        rec["x"][i] = np.nan
    head = _header(
        ["x", "y", "z", "rgb", "normal", "_"],
        [4, 4, 4, 4, 4, 1],
        ["F", "F", "F", rgb_type, "F", "U"],
        [1, 1, 1, 1, 3, 4],
        n,
        height,
        data=data,
    )
    path.write_bytes(head.encode() + rec.tobytes())
    return rec, rgb


@pytest.mark.parametrize("rgb_type", ["F", "U"])
def test_binary_packed_rgb_and_count_fields(tmp_path, rgb_type):
    rec, rgb = _binary_pcd(tmp_path / "b.pcd", rgb_type=rgb_type)
    scan = read_scan(tmp_path / "b.pcd")
    np.testing.assert_array_equal(scan.xyz[:, 2], rec["z"])
    np.testing.assert_array_equal(scan.rgb, rgb)
    assert set(scan.fields) == {"normal"}
    assert scan.fields["normal"].shape == (20, 3)


def test_organised_cloud_drops_nan_points(tmp_path, caplog):
    caplog.set_level(logging.INFO, logger="jointseg.io")
    rec, _ = _binary_pcd(tmp_path / "o.pcd", n=4, height=3, nan_at=(1, 7))
    scan = read_scan(tmp_path / "o.pcd")
    assert len(scan) == 10
    np.testing.assert_array_equal(scan.xyz[:, 1], np.delete(rec["y"], [1, 7]))
    assert "dropped 2 invalid" in caplog.text


def test_unorganised_cloud_with_nan_is_an_error(tmp_path):
    _binary_pcd(tmp_path / "u.pcd", n=12, nan_at=(5,))
    with pytest.raises(ScanFormatError, match=r"point 5 \(record 5\) has non-finite"):
        read_scan(tmp_path / "u.pcd")


def test_binary_compressed_written_by_open3d(tmp_path):
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(2)
    cloud = o3d.geometry.PointCloud()
    pts = rng.random((3000, 3))
    cols = rng.integers(0, 256, (3000, 3))
    cloud.points = o3d.utility.Vector3dVector(pts)
    cloud.colors = o3d.utility.Vector3dVector(cols / 255.0)
    assert o3d.io.write_point_cloud(str(tmp_path / "c.pcd"), cloud, compressed=True)
    assert b"binary_compressed" in (tmp_path / "c.pcd").read_bytes()[:400]
    scan = read_scan(tmp_path / "c.pcd")
    np.testing.assert_allclose(scan.xyz, pts.astype(np.float32), rtol=0, atol=0)
    np.testing.assert_array_equal(scan.rgb, cols)


def test_corrupt_compressed_data(tmp_path):
    head = _header(["x", "y", "z"], [4, 4, 4], ["F"] * 3, [1] * 3, 4, data="binary_compressed")
    body = np.array([10, 48], dtype="<u4").tobytes() + bytes([0xE0, 0xFF] + [0] * 8)
    (tmp_path / "c.pcd").write_bytes(head.encode() + body)
    with pytest.raises(ScanFormatError, match="corrupt binary_compressed"):
        read_scan(tmp_path / "c.pcd")


def test_lzf_round_trip_with_overlapping_reference():
    # literal "ab", then a back-reference of length 8 at distance 2 (overlapping): "abababababab"
    stream = bytes([1]) + b"ab" + bytes([(6 << 5) | 0, 1])
    assert lzf.decompress(stream, 10) == b"ababababab"
    with pytest.raises(lzf.LZFError):
        lzf.decompress(stream, 11)


# --- bad input -----------------------------------------------------------------------------


def test_truncated_binary(tmp_path):
    _binary_pcd(tmp_path / "t.pcd", n=20)
    data = (tmp_path / "t.pcd").read_bytes()
    (tmp_path / "t.pcd").write_bytes(data[: len(data) - 32 * 5])
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"truncated PCD.*20 points.*15 complete"):
            fn(tmp_path / "t.pcd")


def test_binary_header_declares_too_few(tmp_path):
    _binary_pcd(tmp_path / "t.pcd", n=20)
    data = (tmp_path / "t.pcd").read_bytes()
    (tmp_path / "t.pcd").write_bytes(data + data[-32 * 3 :])
    with pytest.raises(ScanFormatError, match="holds 23 points but the header declares 20"):
        read_scan(tmp_path / "t.pcd")


def _ascii_pcd(path, declared, rows):
    path.write_text(
        _header(["x", "y", "z"], [4, 4, 4], ["F"] * 3, [1] * 3, declared)
        + "".join(f"{r}\n" for r in rows)
    )
    return path


def test_ascii_declares_more_than_present(tmp_path):
    path = _ascii_pcd(tmp_path / "a.pcd", 5, ["1 2 3"] * 3)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match="declares 5 points but the file has 3"):
            fn(path)


def test_ascii_declares_fewer_than_present(tmp_path):
    path = _ascii_pcd(tmp_path / "a.pcd", 2, ["1 2 3"] * 4)
    with pytest.raises(ScanFormatError, match="declares 2 points but the file has more"):
        read_scan(path)


def test_ascii_column_mismatch_names_line(tmp_path):
    path = _ascii_pcd(tmp_path / "a.pcd", 3, ["1 2 3", "1 2 3 4", "1 2 3"])
    with pytest.raises(ScanFormatError, match="line 13 has 4 columns, expected 3"):
        read_scan(path)


def test_ascii_nan_names_line(tmp_path):
    path = _ascii_pcd(tmp_path / "a.pcd", 3, ["1 2 3", "1 2 3", "nan 2 3"])
    with pytest.raises(ScanFormatError, match=r"\(line 14\) has non-finite"):
        read_scan(path)


def test_not_a_pcd(tmp_path):
    (tmp_path / "n.pcd").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    with pytest.raises(ScanFormatError, match="not a PCD file"):
        read_scan(tmp_path / "n.pcd")
    (tmp_path / "m.pcd").write_text("hello world\n")
    with pytest.raises(ScanFormatError, match="not a PCD file"):
        read_scan(tmp_path / "m.pcd")


def test_inconsistent_header(tmp_path):
    text = _header(["x", "y", "z"], [4, 4], ["F"] * 3, [1] * 3, 1) + "0 0 0\n"
    (tmp_path / "h.pcd").write_text(text)
    with pytest.raises(ScanFormatError, match="3 FIELDS but 2 SIZE"):
        read_scan(tmp_path / "h.pcd")
    text = _header(["x", "y", "z"], [4] * 3, ["F"] * 3, [1] * 3, 2, points=3) + "0 0 0\n"
    (tmp_path / "p.pcd").write_text(text)
    with pytest.raises(ScanFormatError, match="POINTS 3 but WIDTH"):
        read_scan(tmp_path / "p.pcd")
    text = _header(["x", "y", "intensity"], [4] * 3, ["F"] * 3, [1] * 3, 1) + "0 0 0\n"
    (tmp_path / "z.pcd").write_text(text)
    with pytest.raises(ScanFormatError, match="no scalar z field"):
        read_scan(tmp_path / "z.pcd")


def test_max_points(tmp_path):
    _binary_pcd(tmp_path / "b.pcd", n=20)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"20 points, more than max_points=10"):
            fn(tmp_path / "b.pcd", max_points=10)


def test_the_viewpoint_and_an_organised_size_are_kept_for_the_frame_stage(tmp_path):
    _binary_pcd(tmp_path / "o.pcd", n=4, height=3)
    text = (
        (tmp_path / "o.pcd")
        .read_bytes()
        .replace(b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 0 0 0 0 1 0 0")
    )
    (tmp_path / "v.pcd").write_bytes(text)
    scan = read_scan(tmp_path / "v.pcd")
    assert scan.meta["organised"] == [4, 3]
    assert scan.meta["pcd_viewpoint"] == [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]
    flat = read_scan(_ascii_pcd(tmp_path / "flat.pcd", 2, ["0 0 0", "1 1 1"]))
    assert "organised" not in flat.meta
    assert flat.meta["pcd_viewpoint"] == [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]


def test_a_malformed_viewpoint_is_ignored_with_a_warning(tmp_path, caplog):
    path = _ascii_pcd(tmp_path / "a.pcd", 2, ["0 0 0", "1 1 1"])
    path.write_bytes(path.read_bytes().replace(b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 0 0 x"))
    scan = read_scan(path)
    assert scan.meta["pcd_viewpoint"] == [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    assert "VIEWPOINT" in caplog.text and "malformed" in caplog.text
