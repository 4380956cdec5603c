"""NPY tables and NPZ archives, and bad ones."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.io import ScanFormatError, probe_scan, read_scan


@pytest.mark.parametrize("ncols", [3, 4, 6, 7])
def test_npy_tables(tmp_path, ncols):
    rng = np.random.default_rng(0)
    table = np.column_stack([rng.random((10, 3)), rng.integers(0, 13, (10, ncols - 3))])
    np.save(tmp_path / "t.npy", table.astype(np.float32 if ncols != 7 else np.float64))
    scan = read_scan(tmp_path / "t.npy")
    np.testing.assert_allclose(scan.xyz, table[:, :3], rtol=1e-6)
    assert (scan.rgb is not None) == (ncols >= 6)
    assert (scan.labels is not None) == (ncols == 7)
    assert ("intensity" in scan.fields) == (ncols == 4)
    assert probe_scan(tmp_path / "t.npy").n_points == 10


def test_npz_written_by_hand(tmp_path):
    rng = np.random.default_rng(1)
    xyz = rng.random((8, 3))
    np.savez_compressed(
        tmp_path / "a.npz",
        xyz=xyz,
        rgb=rng.random((8, 3)),
        labels=np.arange(8),
        ring=np.arange(8, dtype=np.uint8),
        feat=np.ones((8, 4), dtype=np.float32),
    )
    scan = read_scan(tmp_path / "a.npz")
    np.testing.assert_array_equal(scan.xyz, xyz)
    assert scan.rgb.dtype == np.uint8
    assert scan.fields["ring"].dtype == np.uint8
    assert scan.fields["feat"].shape == (8, 4)
    info = probe_scan(tmp_path / "a.npz")
    assert (info.n_points, info.has_rgb, info.has_labels) == (8, True, True)
    assert set(info.fields) == {"ring", "feat"}


def test_npy_bad_shape(tmp_path):
    np.save(tmp_path / "b.npy", np.zeros((10, 5)))
    with pytest.raises(ScanFormatError, match=r"\(N, 3\|4\|6\|7\).*\(10, 5\)"):
        read_scan(tmp_path / "b.npy")


def test_npy_object_array_is_refused(tmp_path):
    np.save(tmp_path / "o.npy", np.array([[1, "a", None]], dtype=object), allow_pickle=True)
    with pytest.raises(ScanFormatError, match="o.npy"):
        read_scan(tmp_path / "o.npy")


def test_npy_truncated(tmp_path):
    np.save(tmp_path / "t.npy", np.zeros((100, 3)))
    data = (tmp_path / "t.npy").read_bytes()
    (tmp_path / "t.npy").write_bytes(data[:-80])
    with pytest.raises(ScanFormatError, match="truncated .npy"):
        read_scan(tmp_path / "t.npy")


def test_npy_not_numpy(tmp_path):
    (tmp_path / "n.npy").write_text("1 2 3\n")
    with pytest.raises(ScanFormatError, match="not a valid .npy"):
        read_scan(tmp_path / "n.npy")


def test_npy_nan_names_row(tmp_path):
    table = np.zeros((5, 3))
    table[2, 1] = np.inf
    np.save(tmp_path / "n.npy", table)
    with pytest.raises(ScanFormatError, match=r"point 2 \(row 2\) has non-finite"):
        read_scan(tmp_path / "n.npy")


def test_npz_missing_xyz(tmp_path):
    np.savez(tmp_path / "m.npz", points=np.zeros((3, 3)))
    with pytest.raises(ScanFormatError, match="no 'xyz' array.*points"):
        read_scan(tmp_path / "m.npz")


def test_npz_mismatched_lengths(tmp_path):
    np.savez(tmp_path / "m.npz", xyz=np.zeros((3, 3)), labels=np.zeros(4))
    with pytest.raises(
        ScanFormatError, match="'labels' must be numeric with 3 rows.*got shape \\(4,\\)"
    ):
        read_scan(tmp_path / "m.npz")


def test_npz_object_array_is_refused(tmp_path):
    np.savez(tmp_path / "o.npz", xyz=np.zeros((2, 3)), tag=np.array(["a", None], dtype=object))
    with pytest.raises(ScanFormatError, match="'tag' must be numeric"):
        read_scan(tmp_path / "o.npz")


def test_npz_not_a_zip(tmp_path):
    (tmp_path / "z.npz").write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(ScanFormatError, match="not a valid .npz"):
        read_scan(tmp_path / "z.npz")


def test_npz_truncated(tmp_path):
    np.savez(tmp_path / "t.npz", xyz=np.zeros((1000, 3)))
    data = (tmp_path / "t.npz").read_bytes()
    (tmp_path / "t.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(ScanFormatError, match="t.npz"):
        read_scan(tmp_path / "t.npz")


def test_max_points(tmp_path):
    np.save(tmp_path / "m.npy", np.zeros((50, 3)))
    np.savez(tmp_path / "m.npz", xyz=np.zeros((50, 3)))
    for name in ("m.npy", "m.npz"):
        for fn in (read_scan, probe_scan):
            with pytest.raises(ScanFormatError, match="50 points, more than max_points=20"):
                fn(tmp_path / name, max_points=20)
