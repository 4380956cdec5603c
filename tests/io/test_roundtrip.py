"""Write with our writer, read back, compare: every writable format."""

from __future__ import annotations

import os

import numpy as np
import pytest

from jointseg.io import WRITE_EXTENSIONS, ScanFormatError, read_scan, write_scan
from jointseg.scan import Scan

# Extension -> (xyz tolerance, keeps fields, dtype kept exactly)
FORMATS = {
    ".ply": (0.0, True),
    ".las": (1e-4, True),
    ".laz": (1e-4, True),
    ".pcd": (0.0, True),
    ".npz": (0.0, True),
    ".txt": (0.0, False),
    ".xyz": (0.0, False),
    ".csv": (0.0, False),
}


def test_every_write_extension_is_covered():
    assert set(WRITE_EXTENSIONS) == set(FORMATS)


@pytest.mark.parametrize("ext", sorted(FORMATS))
def test_roundtrip_full_scan(tmp_path, scan, ext):
    tol, keeps_fields = FORMATS[ext]
    path = write_scan(scan, tmp_path / f"room{ext}")
    assert path == tmp_path / f"room{ext}"
    back = read_scan(path)
    assert len(back) == len(scan)
    assert back.source_format == ext[1:]
    np.testing.assert_allclose(back.xyz, scan.xyz, rtol=0, atol=tol)
    np.testing.assert_array_equal(back.rgb, scan.rgb)
    np.testing.assert_array_equal(back.labels, scan.labels)
    if keeps_fields:
        assert set(back.fields) == set(scan.fields)
        for name, values in scan.fields.items():
            np.testing.assert_array_equal(back.fields[name], values, err_msg=name)
            assert back.fields[name].dtype == values.dtype, name
    else:
        assert back.fields == {}


@pytest.mark.parametrize("ext", sorted(FORMATS))
def test_roundtrip_xyz_only(tmp_path, make_scan, ext):
    scan = make_scan(50, rgb=False, labels=False, fields=False)
    back = read_scan(write_scan(scan, tmp_path / f"bare{ext}"))
    np.testing.assert_allclose(back.xyz, scan.xyz, rtol=0, atol=FORMATS[ext][0])
    assert back.rgb is None
    assert back.labels is None
    assert back.fields == {}


@pytest.mark.parametrize("ext", sorted(FORMATS))
def test_roundtrip_labels_without_colour(tmp_path, make_scan, ext):
    scan = make_scan(40, rgb=False, fields=False)
    back = read_scan(write_scan(scan, tmp_path / f"lab{ext}"))
    assert back.rgb is None
    np.testing.assert_array_equal(back.labels, scan.labels)


@pytest.mark.parametrize("ext", [".ply", ".las"])
def test_two_d_field_is_split_into_columns(tmp_path, make_scan, ext):
    scan = make_scan(30, fields=False)
    normals = np.random.default_rng(1).normal(size=(30, 3))
    back = read_scan(write_scan(scan.with_fields(normal=normals), tmp_path / f"n{ext}"))
    for i in range(3):
        np.testing.assert_array_equal(back.fields[f"normal_{i}"], normals[:, i])
    assert "normal" not in back.fields


@pytest.mark.parametrize("ext", [".pcd", ".npz"])
def test_two_d_field_is_kept_whole(tmp_path, make_scan, ext):
    scan = make_scan(30, fields=False)
    normals = np.random.default_rng(1).normal(size=(30, 3)).astype(np.float32)
    back = read_scan(write_scan(scan.with_fields(normal=normals), tmp_path / f"n{ext}"))
    np.testing.assert_array_equal(back.fields["normal"], normals)


def test_split_name_collision_is_refused(tmp_path, make_scan):
    scan = make_scan(10, fields=False).with_fields(n=np.zeros((10, 2)), n_0=np.zeros(10))
    with pytest.raises(ScanFormatError, match="n_0"):
        write_scan(scan, tmp_path / "c.ply")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("ext", [".ply", ".pcd"])
def test_int64_fields_are_narrowed_with_a_check(tmp_path, make_scan, ext):
    scan = make_scan(20, fields=False).with_fields(
        small=np.arange(20, dtype=np.int64), big=np.arange(20, dtype=np.int64) + 2**40
    )
    back = read_scan(write_scan(scan, tmp_path / f"i{ext}"))
    assert back.fields["small"].dtype == np.int32
    np.testing.assert_array_equal(back.fields["small"], np.arange(20))
    assert back.fields["big"].dtype == np.float64
    np.testing.assert_array_equal(back.fields["big"], np.arange(20) + 2**40)
    huge = make_scan(5, fields=False).with_fields(h=np.full(5, 2**60, dtype=np.int64))
    with pytest.raises(ScanFormatError, match="'h'"):
        write_scan(huge, tmp_path / f"h{ext}")


def test_bool_field_becomes_uint8_in_ply(tmp_path, make_scan):
    flag = np.arange(10) % 2 == 0
    back = read_scan(write_scan(make_scan(10).with_fields(flag=flag), tmp_path / "b.ply"))
    np.testing.assert_array_equal(back.fields["flag"], flag.astype(np.uint8))


def test_las_keeps_int64_and_whole_number_intensity(tmp_path, make_scan):
    scan = make_scan(20, fields=False).with_fields(
        intensity=np.arange(20, dtype=np.uint16) * 1000, big=np.arange(20, dtype=np.int64) << 40
    )
    back = read_scan(write_scan(scan, tmp_path / "i.las"))
    np.testing.assert_array_equal(back.fields["intensity"], scan.fields["intensity"])
    np.testing.assert_array_equal(back.fields["big"], scan.fields["big"])
    assert back.fields["big"].dtype == np.int64


def test_las_scale_coarsens_for_huge_extent(tmp_path, make_scan):
    scan = make_scan(20, fields=False, extent=1.0)
    far = Scan(xyz=scan.xyz * np.array([1e6, 1, 1]), rgb=scan.rgb, labels=scan.labels)
    back = read_scan(write_scan(far, tmp_path / "far.las"))
    extent = np.ptp(far.xyz, axis=0).max()
    assert extent / 1e-4 > 2**31  # 0.1 mm would overflow int32
    np.testing.assert_allclose(back.xyz, far.xyz, rtol=0, atol=1e-3)


def test_overwrite_replaces_existing_file(tmp_path, make_scan):
    target = tmp_path / "s.ply"
    write_scan(make_scan(10, seed=1), target)
    second = make_scan(20, seed=2)
    write_scan(second, target)
    assert len(read_scan(target)) == 20
    assert [p.name for p in tmp_path.iterdir()] == ["s.ply"]


def test_failed_write_leaves_target_and_no_temp_file(tmp_path, make_scan, monkeypatch):
    target = tmp_path / "s.ply"
    write_scan(make_scan(10), target)
    before = target.read_bytes()

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="disk full"):
        write_scan(make_scan(30), target)
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["s.ply"]


def test_bad_field_dtype_leaves_nothing(tmp_path, make_scan):
    scan = make_scan(5, fields=False).with_fields(when=np.array(["a"] * 5))
    for ext in (".ply", ".las", ".pcd", ".npz"):
        with pytest.raises(ScanFormatError, match="when"):
            write_scan(scan, tmp_path / f"w{ext}")
    assert list(tmp_path.iterdir()) == []


def test_write_errors(tmp_path, scan):
    with pytest.raises(ScanFormatError, match=r"\.ply.*\.las"):
        write_scan(scan, tmp_path / "x.obj")
    with pytest.raises(ScanFormatError, match="does not exist"):
        write_scan(scan, tmp_path / "missing" / "x.ply")
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(ScanFormatError, match="is a directory"):
        write_scan(scan, tmp_path / "d.ply")
    with pytest.raises(ScanFormatError, match="cannot write"):
        write_scan(scan, tmp_path / "x.e57")


def test_written_file_permissions_follow_umask(tmp_path, scan):
    path = write_scan(scan, tmp_path / "p.npz")
    mask = os.umask(0)
    os.umask(mask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~mask


def test_progress_is_reported(tmp_path, scan):
    calls = []
    path = write_scan(scan, tmp_path / "p.ply", progress=lambda s, f: calls.append((s, f)))
    read_scan(path, progress=lambda s, f: calls.append((s, f)))
    assert ("write", 1.0) in calls and ("read", 1.0) in calls
    assert all(0.0 <= f <= 1.0 for _, f in calls)
