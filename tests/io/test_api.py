"""The public entry points: format detection, input checks, probing, error types."""

from __future__ import annotations

import numpy as np
import pytest

import jointseg.io as jio
from jointseg.exceptions import ConfigError, JointsegError
from jointseg.io import (
    READ_EXTENSIONS,
    WRITE_EXTENSIONS,
    ScanFormatError,
    ScanInfo,
    detect_format,
    probe_scan,
    read_scan,
    write_scan,
)


def test_public_names():
    assert jio.ScanFormatError is ScanFormatError
    assert issubclass(ScanFormatError, JointsegError) and issubclass(ScanFormatError, ValueError)
    assert {
        ".ply",
        ".las",
        ".laz",
        ".e57",
        ".pcd",
        ".txt",
        ".xyz",
        ".csv",
        ".npy",
        ".npz",
        ".glb",
        ".gltf",
        ".obj",
    } == set(READ_EXTENSIONS)
    assert set(WRITE_EXTENSIONS) <= set(READ_EXTENSIONS)
    for name in jio.__all__:
        assert hasattr(jio, name)


@pytest.mark.parametrize(
    ("name", "fmt"),
    [
        ("a.ply", "ply"),
        ("A.PLY", "ply"),
        ("b.las", "las"),
        ("b.laz", "laz"),
        ("c.e57", "e57"),
        ("d.pcd", "pcd"),
        ("e.txt", "txt"),
        ("e.xyz", "xyz"),
        ("e.csv", "csv"),
        ("f.npy", "npy"),
        ("f.npz", "npz"),
    ],
)
def test_detect_format(name, fmt, tmp_path):
    assert detect_format(tmp_path / name) == fmt


def test_unknown_extension_lists_supported(tmp_path):
    (tmp_path / "a.stl").write_text("solid a\n")
    with pytest.raises(ScanFormatError, match=r"unsupported file extension '.stl'.*\.ply.*\.obj"):
        read_scan(tmp_path / "a.stl")
    (tmp_path / "noext").write_text("0 0 0\n")
    with pytest.raises(ScanFormatError, match="unsupported file extension"):
        read_scan(tmp_path / "noext")


def test_missing_file(tmp_path):
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match="file not found"):
            fn(tmp_path / "nope.ply")


@pytest.mark.parametrize("ext", sorted(set(READ_EXTENSIONS)))
def test_empty_file_every_format(tmp_path, ext):
    (tmp_path / f"e{ext}").write_bytes(b"")
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"empty \(0 bytes\)"):
            fn(tmp_path / f"e{ext}")


@pytest.mark.parametrize("ext", sorted(set(READ_EXTENSIONS)))
def test_directory_where_file_expected(tmp_path, ext):
    (tmp_path / f"d{ext}").mkdir()
    with pytest.raises(ScanFormatError, match="is a directory"):
        read_scan(tmp_path / f"d{ext}")


@pytest.mark.parametrize(
    "ext", [".ply", ".las", ".laz", ".e57", ".pcd", ".npy", ".npz", ".glb", ".gltf", ".obj"]
)
def test_wrong_content_for_extension(tmp_path, ext):
    (tmp_path / f"w{ext}").write_text("this is not a point cloud\n" * 20)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=f"w{ext}"):
            fn(tmp_path / f"w{ext}")


@pytest.mark.parametrize("ext", sorted(WRITE_EXTENSIONS))
def test_probe_matches_read(tmp_path, make_scan, ext):
    scan = make_scan(64)
    path = write_scan(scan, tmp_path / f"p{ext}")
    info = probe_scan(path)
    assert isinstance(info, ScanInfo)
    back = read_scan(path)
    assert info.n_points == len(back) == 64
    assert info.has_rgb == (back.rgb is not None)
    assert info.has_labels == (back.labels is not None)
    assert set(back.fields) <= set(info.fields) | {"raw_label"}


def test_max_points_must_be_positive(tmp_path, scan):
    path = write_scan(scan, tmp_path / "s.ply")
    with pytest.raises(ConfigError, match="max_points"):
        read_scan(path, max_points=0)


def test_reserved_names_from_files_do_not_break_scan(tmp_path):
    np.savez(tmp_path / "r.npz", xyz=np.zeros((2, 3)), red=np.ones(2))
    scan = read_scan(tmp_path / "r.npz")
    np.testing.assert_array_equal(scan.fields["red_field"], [1, 1])


def test_unreadable_file(tmp_path, scan, monkeypatch):
    path = write_scan(scan, tmp_path / "s.npz")
    import numpy

    def fail(*args, **kwargs):
        raise OSError("Input/output error")

    monkeypatch.setattr(numpy, "load", fail)
    with pytest.raises(ScanFormatError, match="Input/output error"):
        read_scan(path)
