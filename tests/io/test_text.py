"""TXT / XYZ / CSV point lists: column layouts, separators, headers, bad lines."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.io import ScanFormatError, probe_scan, read_scan, write_scan


def _write(path, lines):
    path.write_text("".join(f"{line}\n" for line in lines))
    return path


def test_s3dis_style_six_columns(tmp_path):
    path = _write(tmp_path / "room.txt", ["1.000 2.000 3.000 10 20 30", "4.5 5.5 6.5 255 0 7"])
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.xyz, [[1, 2, 3], [4.5, 5.5, 6.5]])
    np.testing.assert_array_equal(scan.rgb, [[10, 20, 30], [255, 0, 7]])
    assert scan.labels is None and scan.fields == {}


@pytest.mark.parametrize("sep", [" ", "\t", ",", ", "])
def test_separators_and_seven_columns(tmp_path, sep):
    rows = [sep.join(map(str, [i, i + 0.5, -i, 1, 2, 3, i % 13])) for i in range(30)]
    scan = read_scan(_write(tmp_path / "p.xyz", rows))
    np.testing.assert_array_equal(scan.labels, np.arange(30) % 13)
    np.testing.assert_array_equal(scan.xyz[:, 1], np.arange(30) + 0.5)


def test_three_and_four_columns(tmp_path):
    assert read_scan(_write(tmp_path / "a.txt", ["0 0 0", "1 1 1"])).rgb is None
    scan = read_scan(_write(tmp_path / "b.txt", ["0 0 0 0.3", "1 1 1 0.7"]))
    np.testing.assert_array_equal(scan.fields["intensity"], [0.3, 0.7])


def test_float_colours_in_unit_range_are_scaled(tmp_path):
    scan = read_scan(_write(tmp_path / "f.txt", ["0 0 0 0.0 0.5 1.0", "1 1 1 1 1 1"]))
    np.testing.assert_array_equal(scan.rgb, [[0, 128, 255], [255, 255, 255]])


def test_cloudcompare_header(tmp_path):
    path = _write(tmp_path / "cc.csv", ["//X,Y,Z,R,G,B", "1,2,3,4,5,6", "", "7,8,9,10,11,12", ""])
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.rgb, [[4, 5, 6], [10, 11, 12]])
    assert probe_scan(path).n_points >= 2


def test_named_header_with_fields(tmp_path):
    path = _write(tmp_path / "n.txt", ["x y z class intensity return", "1 2 3 4 0.5 1"])
    scan = read_scan(path)
    np.testing.assert_array_equal(scan.labels, [4])
    assert set(scan.fields) == {"intensity", "return"}
    info = probe_scan(path)
    assert info.has_labels and not info.has_rgb and set(info.fields) == {"intensity", "return"}


def test_labels_without_colour_round_trip_through_header(tmp_path, make_scan):
    scan = make_scan(20, rgb=False, fields=False)
    path = write_scan(scan, tmp_path / "l.txt")
    assert path.read_text().startswith("//x y z label")
    np.testing.assert_array_equal(read_scan(path).labels, scan.labels)


def test_windows_line_endings(tmp_path):
    (tmp_path / "w.txt").write_bytes(b"1 2 3 4 5 6\r\n7 8 9 10 11 12\r\n")
    assert len(read_scan(tmp_path / "w.txt")) == 2


def test_large_file_across_chunks(tmp_path, monkeypatch, make_scan):
    from jointseg.io import tabular

    monkeypatch.setattr(tabular, "CHUNK_BYTES", 1000)
    scan = make_scan(2000, fields=False)
    back = read_scan(write_scan(scan, tmp_path / "big.txt"))
    np.testing.assert_array_equal(back.xyz, scan.xyz)
    np.testing.assert_array_equal(back.labels, scan.labels)
    lines = ["0 0 0 1 1 1"] * 1500 + ["0 0 0 1 1"]
    with pytest.raises(ScanFormatError, match="line 1501 has 5 columns, expected 6"):
        read_scan(_write(tmp_path / "bad.txt", lines))


# --- bad input -----------------------------------------------------------------------------


def test_mismatched_columns_names_line(tmp_path):
    path = _write(tmp_path / "m.txt", ["1 2 3 4 5 6", "1 2 3 4 5 6", "1 2 3 4 5", "1 2 3 4 5 6"])
    with pytest.raises(ScanFormatError, match=r"m.txt: line 3 has 5 columns, expected 6"):
        read_scan(path)


def test_mismatched_columns_after_header_counts_header_line(tmp_path):
    path = _write(tmp_path / "m.csv", ["x,y,z", "1,2,3", "1,2,3,4"])
    with pytest.raises(ScanFormatError, match="line 3 has 4 columns, expected 3"):
        read_scan(path)


def test_non_numeric_token_names_line(tmp_path):
    path = _write(tmp_path / "t.txt", ["1 2 3", "4 5 6", "7 8 nine"])
    with pytest.raises(ScanFormatError, match="line 3: cannot read 'nine'"):
        read_scan(path)


def test_nan_coordinate_names_line(tmp_path):
    path = _write(tmp_path / "n.txt", ["", "1 2 3", "4 nan 6"])
    with pytest.raises(ScanFormatError, match=r"point 1 \(line 3\) has non-finite"):
        read_scan(path)


def test_unsupported_column_count(tmp_path):
    with pytest.raises(ScanFormatError, match="rows have 5 columns; expected 3"):
        read_scan(_write(tmp_path / "five.txt", ["1 2 3 4 5"]))


def test_header_only_and_blank(tmp_path):
    with pytest.raises(ScanFormatError, match="no data lines"):
        read_scan(_write(tmp_path / "h.txt", ["//X Y Z"]))
    with pytest.raises(ScanFormatError, match="no data lines"):
        read_scan(_write(tmp_path / "b.txt", ["", "  "]))
    (tmp_path / "e.txt").write_bytes(b"")
    with pytest.raises(ScanFormatError, match="empty"):
        read_scan(tmp_path / "e.txt")


def test_two_header_lines(tmp_path):
    with pytest.raises(ScanFormatError, match="line 2 is not numeric"):
        read_scan(_write(tmp_path / "h.txt", ["x y z", "a b c", "1 2 3"]))


def test_binary_garbage(tmp_path):
    (tmp_path / "g.txt").write_bytes(b"\xff\xfe\x00\x01" * 50)
    with pytest.raises(ScanFormatError, match="g.txt"):
        read_scan(tmp_path / "g.txt")


def test_fractional_label(tmp_path):
    with pytest.raises(ScanFormatError, match="whole numbers"):
        read_scan(_write(tmp_path / "l.txt", ["1 2 3 4 5 6 1.5"]))


def test_max_points(tmp_path):
    path = _write(tmp_path / "m.txt", ["1 2 3"] * 100)
    with pytest.raises(ScanFormatError, match="100 points, more than max_points=10"):
        read_scan(path, max_points=10)
    with pytest.raises(ScanFormatError, match="100 points, more than max_points=10"):
        probe_scan(path, max_points=10)
    long_lines = _write(tmp_path / "l.txt", ["1.000000000 2.000000000 3.000000000"] * 100)
    with pytest.raises(ScanFormatError, match="more than max_points=10"):
        read_scan(long_lines, max_points=10)


def test_utf8_bom(tmp_path):
    (tmp_path / "bom.txt").write_bytes(b"\xef\xbb\xbf1 2 3\n4 5 6\n")
    assert len(read_scan(tmp_path / "bom.txt")) == 2
    (tmp_path / "bomh.csv").write_bytes(b"\xef\xbb\xbfX,Y,Z,Label\n1,2,3,4\n")
    np.testing.assert_array_equal(read_scan(tmp_path / "bomh.csv").labels, [4])
