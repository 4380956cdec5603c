"""PLY reading: encodings, colour and label spellings, and every kind of bad file."""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from jointseg.io import ScanFormatError, probe_scan, read_scan, write_scan


def _vertex(n: int, extra: list[tuple[str, str, np.ndarray]], seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    cols = [("x", "f4", rng.random(n)), ("y", "f4", rng.random(n)), ("z", "f4", rng.random(n))]
    cols += extra
    data = np.empty(n, dtype=[(name, dt) for name, dt, _ in cols])
    for name, _, values in cols:
        data[name] = values
    return data


def _write(path, data, *, text=False, byte_order="=", faces=None):
    elements = [PlyElement.describe(data, "vertex")]
    if faces is not None:
        elements.append(faces)
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))
    return path


@pytest.mark.parametrize(
    ("text", "order"), [(True, "="), (False, "<"), (False, ">")], ids=["ascii", "le", "be"]
)
def test_encodings(tmp_path, text, order):
    rgb = np.random.default_rng(3).integers(0, 256, (40, 3))
    data = _vertex(
        40,
        [
            ("red", "u1", rgb[:, 0]),
            ("green", "u1", rgb[:, 1]),
            ("blue", "u1", rgb[:, 2]),
            ("label", "i4", np.arange(40) % 13 - 1),
            ("nx", "f4", np.linspace(0, 1, 40)),
        ],
    )
    scan = read_scan(_write(tmp_path / "a.ply", data, text=text, byte_order=order))
    np.testing.assert_allclose(scan.xyz[:, 0], data["x"], rtol=1e-6)
    np.testing.assert_array_equal(scan.rgb, rgb)
    np.testing.assert_array_equal(scan.labels, np.arange(40) % 13 - 1)
    np.testing.assert_allclose(scan.fields["nx"], data["nx"], rtol=1e-6)
    assert scan.fields["nx"].dtype == np.float32


def test_faces_after_vertices_make_a_mesh_sampled_on_them(tmp_path):
    """A PLY with faces is a mesh (issue 41): its points are sampled on the faces (the mesh
    readers' tests are in test_mesh.py); an empty face element leaves a point cloud."""
    faces = PlyElement.describe(
        np.array([([0, 1, 2],), ([1, 2, 3],)], dtype=[("vertex_indices", "i4", (3,))]), "face"
    )
    for text in (True, False):
        path = _write(tmp_path / f"m{text}.ply", _vertex(4, []), text=text, faces=faces)
        scan = read_scan(path)
        assert scan.meta["mesh"]["faces"] == 2 and scan.meta["mesh"]["vertices"] == 4
        assert len(scan) == scan.meta["mesh"]["sampled_points"] > 4
    no_faces = PlyElement.describe(np.zeros(0, dtype=[("vertex_indices", "i4", (3,))]), "face")
    path = _write(tmp_path / "cloud.ply", _vertex(4, []), faces=no_faces)
    assert len(read_scan(path)) == 4 and "mesh" not in read_scan(path).meta


@pytest.mark.parametrize(
    ("names", "dtype", "values", "expected"),
    [
        (("r", "g", "b"), "u1", [0, 128, 255], [0, 128, 255]),
        (("diffuse_red", "diffuse_green", "diffuse_blue"), "u1", [1, 2, 3], [1, 2, 3]),
        (("red", "green", "blue"), "u2", [0, 257 * 128, 65535], [0, 128, 255]),
        (("red", "green", "blue"), "f4", [0.0, 0.5, 1.0], [0, 128, 255]),
        (("red", "green", "blue"), "f4", [0.0, 100.0, 255.0], [0, 100, 255]),
        (("Red", "Green", "Blue"), "u1", [9, 8, 7], [9, 8, 7]),
    ],
)
def test_colour_spellings_and_types(tmp_path, names, dtype, values, expected):
    cols = [(name, dtype, np.full(3, v)) for name, v in zip(names, values, strict=True)]
    scan = read_scan(_write(tmp_path / "c.ply", _vertex(3, cols)))
    np.testing.assert_array_equal(scan.rgb, np.tile(expected, (3, 1)))
    assert scan.fields == {}


@pytest.mark.parametrize(
    ("name", "dtype"),
    [
        ("label", "i4"),
        ("class", "u1"),
        ("classification", "i2"),
        ("scalar_Classification", "f4"),
        ("scalar_label", "f8"),
        ("LABEL", "i4"),
    ],
)
def test_label_property_names(tmp_path, name, dtype):
    values = np.array([0, 5, 12, -1]) if dtype[0] != "u" else np.array([0, 5, 12, 3])
    scan = read_scan(_write(tmp_path / "l.ply", _vertex(4, [(name, dtype, values)])))
    np.testing.assert_array_equal(scan.labels, values)
    assert scan.labels.dtype == np.int32
    assert scan.fields == {}


def test_out_of_range_labels_are_unlabelled_and_kept(tmp_path, caplog):
    path = _write(tmp_path / "l.ply", _vertex(3, [("label", "i4", np.array([3, 40, -7]))]))
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.labels, [3, -1, -1])
    np.testing.assert_array_equal(scan.fields["raw_label"], [3, 40, -7])
    assert "outside the S3DIS classes" in caplog.text


def test_fractional_label_is_refused(tmp_path):
    path = _write(tmp_path / "l.ply", _vertex(3, [("scalar_label", "f4", np.array([1, 2.5, 3]))]))
    with pytest.raises(ScanFormatError, match="whole numbers; point 1 has 2.5"):
        read_scan(path)


def test_probe(tmp_path):
    path = _write(
        tmp_path / "p.ply",
        _vertex(
            7,
            [
                ("red", "u1", np.zeros(7)),
                ("green", "u1", np.zeros(7)),
                ("blue", "u1", np.zeros(7)),
                ("quality", "f4", np.zeros(7)),
            ],
        ),
    )
    info = probe_scan(path)
    assert (info.format, info.n_points, info.has_rgb, info.has_labels) == ("ply", 7, True, False)
    assert info.fields == ("quality",)


# --- bad input -----------------------------------------------------------------------------


def _binary_ply(tmp_path, n_declared, n_written, name="b.ply"):
    header = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {n_declared}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    ).encode()
    path = tmp_path / name
    path.write_bytes(header + np.zeros((n_written, 3), dtype="<f4").tobytes())
    return path


def _ascii_ply(tmp_path, n_declared, rows, name="a.ply"):
    header = (
        f"ply\nformat ascii 1.0\nelement vertex {n_declared}\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    path = tmp_path / name
    path.write_text(header + "".join(f"{r}\n" for r in rows))
    return path


def test_empty_file(tmp_path):
    (tmp_path / "e.ply").write_bytes(b"")
    with pytest.raises(ScanFormatError, match="empty"):
        read_scan(tmp_path / "e.ply")


def test_wrong_magic(tmp_path):
    (tmp_path / "n.ply").write_text("solid cube\nfacet normal 0 0 1\n")
    with pytest.raises(ScanFormatError, match="not a PLY file"):
        read_scan(tmp_path / "n.ply")


def test_header_without_end(tmp_path):
    (tmp_path / "h.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\n")
    with pytest.raises(ScanFormatError, match="end_header"):
        read_scan(tmp_path / "h.ply")


def test_unknown_property_type(tmp_path):
    (tmp_path / "t.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty half y\n"
        "end_header\n0 0\n"
    )
    with pytest.raises(ScanFormatError, match="header line 5"):
        read_scan(tmp_path / "t.ply")


def test_truncated_binary(tmp_path):
    path = _binary_ply(tmp_path, 100, 60)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"truncated.*100 vertices.*60 complete"):
            fn(path)


def test_binary_header_declares_too_few(tmp_path):
    path = _binary_ply(tmp_path, 10, 15)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"longer than the header declares \(10 vert"):
            fn(path)


def test_ascii_header_declares_too_many(tmp_path):
    path = _ascii_ply(tmp_path, 5, ["0 0 0"] * 3)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match="declares 5 vertices but the file has only 3"):
            fn(path)


def test_ascii_header_declares_too_few(tmp_path):
    path = _ascii_ply(tmp_path, 2, ["0 0 0"] * 4)
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match="2 more lines than the header declares"):
            fn(path)


def test_ascii_trailing_blank_lines_are_fine(tmp_path):
    path = _ascii_ply(tmp_path, 2, ["0 0 0", "1 1 1", "", ""])
    assert len(read_scan(path)) == 2


def test_ascii_wrong_column_count_names_line(tmp_path):
    path = _ascii_ply(tmp_path, 3, ["0 0 0", "1 1", "2 2 2"])
    with pytest.raises(ScanFormatError, match="line 9 has 2 columns, expected 3"):
        read_scan(path)


def test_ascii_bad_number_names_line(tmp_path):
    path = _ascii_ply(tmp_path, 3, ["0 0 0", "1 1 1", "2 x 2"])
    with pytest.raises(ScanFormatError, match="line 10: cannot read 'x'"):
        read_scan(path)


def test_no_vertex_element(tmp_path):
    (tmp_path / "f.ply").write_text(
        "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
        "end_header\n3 0 1 2\n"
    )
    with pytest.raises(ScanFormatError, match="no 'vertex' element"):
        read_scan(tmp_path / "f.ply")


def test_no_z_property(tmp_path):
    (tmp_path / "xy.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
        "end_header\n0 0\n"
    )
    with pytest.raises(ScanFormatError, match="no z property"):
        read_scan(tmp_path / "xy.ply")


def test_nan_coordinates_binary_names_point(tmp_path):
    data = _vertex(5, [])
    data["y"][3] = np.nan
    with pytest.raises(ScanFormatError, match=r"point 3 has non-finite"):
        read_scan(_write(tmp_path / "nan.ply", data))


def test_inf_coordinates_ascii_names_line(tmp_path):
    path = _ascii_ply(tmp_path, 3, ["0 0 0", "1 inf 1", "2 2 2"])
    with pytest.raises(ScanFormatError, match=r"point 1 \(line 9\) has non-finite"):
        read_scan(path)


def test_max_points_checked_from_header(tmp_path):
    path = _binary_ply(tmp_path, 1000, 3)  # body is truncated: the header check must come first
    for fn in (read_scan, probe_scan):
        with pytest.raises(ScanFormatError, match=r"1,000 points, more than max_points=500"):
            fn(path, max_points=500)


def test_zero_vertices(tmp_path):
    with pytest.raises(ScanFormatError, match="no points"):
        read_scan(_binary_ply(tmp_path, 0, 0))


def test_directory_named_ply(tmp_path):
    (tmp_path / "dir.ply").mkdir()
    with pytest.raises(ScanFormatError, match="is a directory"):
        read_scan(tmp_path / "dir.ply")


def test_large_binary_reads_fast(tmp_path, make_scan):
    import time

    scan = make_scan(200_000, fields=False)
    path = write_scan(scan, tmp_path / "big.ply")
    start = time.perf_counter()
    back = read_scan(path)
    assert time.perf_counter() - start < 1.0
    np.testing.assert_array_equal(back.xyz, scan.xyz)


def test_list_element_before_vertices(tmp_path):
    """A list element other than faces before the vertices hides their offset: plyfile finds
    them (faces there would make the file a mesh)."""
    grid = PlyElement.describe(
        np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))]), "range_grid"
    )
    vertex = PlyElement.describe(_vertex(5, []), "vertex")
    PlyData([grid, vertex], text=False).write(str(tmp_path / "fv.ply"))
    assert len(read_scan(tmp_path / "fv.ply")) == 5
    PlyData([grid, vertex], text=True).write(str(tmp_path / "fva.ply"))
    assert len(read_scan(tmp_path / "fva.ply")) == 5


def test_odd_field_names_are_made_safe(tmp_path, make_scan):
    scan = make_scan(5, fields=False).with_fields(**{"return number": np.arange(5)})
    back = read_scan(write_scan(scan, tmp_path / "o.ply"))
    np.testing.assert_array_equal(back.fields["return_number"], np.arange(5))
