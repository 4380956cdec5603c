"""E57 files written with pye57's writer: several posed scans are merged in one frame."""

from __future__ import annotations

import numpy as np
import pytest

pye57 = pytest.importorskip("pye57")

from jointseg.io import ScanFormatError, probe_scan, read_scan  # noqa: E402


def _scan_data(n, seed, *, colour=True, intensity=True):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-2, 2, (n, 3))
    data = {"cartesianX": xyz[:, 0], "cartesianY": xyz[:, 1], "cartesianZ": xyz[:, 2]}
    rgb = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    if colour:
        data.update(colorRed=rgb[:, 0], colorGreen=rgb[:, 1], colorBlue=rgb[:, 2])
    if intensity:
        data["intensity"] = rng.random(n).astype(np.float32)
    return data, xyz, rgb


def _write_e57(path, scans):
    with pye57.E57(str(path), mode="w") as e57:
        for data, rotation, translation in scans:
            e57.write_scan_raw(data, rotation=rotation, translation=translation)


def test_two_posed_scans_are_merged(tmp_path):
    # 90° about z: (x, y, z) -> (-y, x, z)
    quarter = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    d1, xyz1, rgb1 = _scan_data(100, 1)
    d2, xyz2, rgb2 = _scan_data(60, 2)
    _write_e57(
        tmp_path / "p.e57",
        [
            (d1, np.array([1.0, 0, 0, 0]), np.array([10.0, 0, 0])),
            (d2, quarter, np.array([0.0, 5.0, 1.0])),
        ],
    )
    scan = read_scan(tmp_path / "p.e57")
    assert len(scan) == 160 and scan.source_format == "e57"
    expected2 = np.column_stack([-xyz2[:, 1], xyz2[:, 0], xyz2[:, 2]]) + [0.0, 5.0, 1.0]
    np.testing.assert_allclose(scan.xyz[:100], xyz1 + [10.0, 0, 0], atol=1e-5)
    np.testing.assert_allclose(scan.xyz[100:], expected2, atol=1e-5)
    np.testing.assert_array_equal(scan.rgb, np.vstack([rgb1, rgb2]))
    assert scan.labels is None
    np.testing.assert_allclose(scan.fields["intensity"][:100], d1["intensity"], rtol=1e-6)
    info = probe_scan(tmp_path / "p.e57")
    assert (info.n_points, info.has_rgb, info.fields) == (160, True, ("intensity",))


def test_scan_without_colour(tmp_path):
    d, xyz, _ = _scan_data(30, 3, colour=False, intensity=False)
    _write_e57(tmp_path / "g.e57", [(d, np.array([1.0, 0, 0, 0]), np.zeros(3))])
    scan = read_scan(tmp_path / "g.e57")
    assert scan.rgb is None and scan.fields == {}
    np.testing.assert_allclose(scan.xyz, xyz, atol=1e-5)


def test_not_an_e57(tmp_path):
    (tmp_path / "x.e57").write_bytes(b"ply\nformat ascii 1.0\n")
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match="not an E57 file"):
            fn(tmp_path / "x.e57")


def test_corrupt_e57(tmp_path):
    d, _, _ = _scan_data(500, 4)
    _write_e57(tmp_path / "c.e57", [(d, np.array([1.0, 0, 0, 0]), np.zeros(3))])
    data = (tmp_path / "c.e57").read_bytes()
    (tmp_path / "c.e57").write_bytes(data[: len(data) // 2])
    with pytest.raises(ScanFormatError, match="c.e57"):
        read_scan(tmp_path / "c.e57")


def test_max_points(tmp_path):
    d, _, _ = _scan_data(40, 5)
    _write_e57(tmp_path / "m.e57", [(d, np.array([1.0, 0, 0, 0]), np.zeros(3))] * 2)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match="80 points, more than max_points=50"):
            fn(tmp_path / "m.e57", max_points=50)


def _garbage_e57(folder, case):
    """An E57 libE57Format refuses: the magic then noise, the magic then zeros, a valid file cut
    short or with bytes overwritten in its middle."""
    path = folder / f"{case}.e57"
    if case in ("noise", "zeros"):
        rng = np.random.default_rng(0)
        body = rng.bytes(3000) if case == "noise" else bytes(3000)
        path.write_bytes(b"ASTM-E57" + body)
        return path
    d, _, _ = _scan_data(2000, 6)
    _write_e57(path, [(d, np.array([1.0, 0, 0, 0]), np.zeros(3))])
    data = bytearray(path.read_bytes())
    if case == "cut":
        data = data[: len(data) // 3]
    else:
        data[len(data) // 2 : len(data) // 2 + 64] = b"\xff" * 64
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("case", ["noise", "zeros", "cut", "overwritten"])
def test_a_garbage_e57_is_one_line_without_the_librarys_debug_text(tmp_path, case):
    path = _garbage_e57(tmp_path, case)
    # the points' pages are read only by read_scan: the probe may not see them
    for fn in (read_scan,) if case == "overwritten" else (probe_scan, read_scan):
        with pytest.raises(ScanFormatError) as refused:
            fn(path)
        message = str(refused.value)
        assert "\n" not in message
        assert message.startswith(f"{path}: ")
        rest = message.removeprefix(f"{path}: ")
        assert "/" not in rest and "\\" not in rest  # no source or server paths
        for debug in ("libE57", ".cpp", "Debug info", "context:", "Got an e57 exception"):
            assert debug not in rest
        assert "E57" in rest  # says what is wrong: not a readable E57 file
