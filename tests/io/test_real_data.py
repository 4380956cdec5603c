"""The two real scans in ../shared/data (skipped when absent; never copied into the repo)."""

from __future__ import annotations

import numpy as np

from jointseg.classes import NUM_CLASSES
from jointseg.io import probe_scan, read_scan, write_scan


def test_s3dis_fragment_ply(shared_data, tmp_path):
    path = shared_data / "s3dis_fragment.ply"
    if not path.exists():
        import pytest

        pytest.skip(f"{path} is not present")
    scan = read_scan(path)
    assert len(scan) == 41_568
    assert scan.source_format == "ply"
    assert scan.rgb is not None and scan.rgb.any()
    assert scan.labels is not None
    assert scan.labels.min() >= -1 and scan.labels.max() < NUM_CLASSES
    assert len(np.unique(scan.labels)) >= 3
    assert scan.fields == {}
    extent = np.ptp(scan.xyz, axis=0)
    assert (extent > 0.5).all() and (extent < 100).all()
    info = probe_scan(path)
    assert (info.n_points, info.has_rgb, info.has_labels) == (41_568, True, True)
    for ext in (".las", ".pcd"):
        back = read_scan(write_scan(scan, tmp_path / f"frag{ext}"))
        np.testing.assert_array_equal(back.labels, scan.labels)
        np.testing.assert_allclose(back.xyz, scan.xyz, atol=1e-4)


def test_real_indoor_pcd(shared_data):
    path = shared_data / "real_indoor_unlabelled.pcd"
    if not path.exists():
        import pytest

        pytest.skip(f"{path} is not present")
    scan = read_scan(path)
    assert len(scan) == 113_662
    assert scan.source_format == "pcd"
    assert scan.labels is None
    assert scan.rgb is not None and scan.rgb.any()
    assert set(scan.fields) == {"normal_x", "normal_y", "normal_z", "curvature"}
    normals = np.stack([scan.fields[f"normal_{a}"] for a in "xyz"], axis=1)
    lengths = np.linalg.norm(normals[np.isfinite(normals).all(axis=1)], axis=1)
    assert np.median(np.abs(lengths - 1)) < 1e-3
    assert probe_scan(path).n_points == 113_662
