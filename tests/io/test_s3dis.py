"""S3DIS room folders built in tmp_path."""

from __future__ import annotations

import numpy as np
import pytest

from jointseg.classes import CLASS_INDEX
from jointseg.io import ScanFormatError, detect_format, probe_scan, read_scan


def _room(tmp_path, objects):
    room = tmp_path / "office_1"
    (room / "Annotations").mkdir(parents=True)
    rng = np.random.default_rng(0)
    whole = []
    for name, n in objects.items():
        rows = np.column_stack([rng.random((n, 3)) * 5, rng.integers(0, 256, (n, 3))])
        lines = [f"{x:.3f} {y:.3f} {z:.3f} {int(r)} {int(g)} {int(b)}" for x, y, z, r, g, b in rows]
        (room / "Annotations" / f"{name}.txt").write_text("\n".join(lines) + "\n")
        whole += lines
    (room / "office_1.txt").write_text("\n".join(whole) + "\n")
    return room


def test_room_folder(tmp_path):
    room = _room(
        tmp_path,
        {"ceiling_1": 5, "chair_1": 3, "chair_2": 4, "stairs_1": 2, "wall_10": 6, "wall_2": 1},
    )
    (room / "Annotations" / ".DS_Store").write_bytes(b"\x00")
    assert detect_format(room) == "s3dis"
    scan = read_scan(room)
    assert len(scan) == 21
    assert scan.source_format == "s3dis"
    counts = {
        int(k): int(v) for k, v in zip(*np.unique(scan.labels, return_counts=True), strict=True)
    }
    assert counts == {
        CLASS_INDEX["ceiling"]: 5,
        CLASS_INDEX["chair"]: 7,
        CLASS_INDEX["clutter"]: 2,
        CLASS_INDEX["wall"]: 7,
    }
    instance = scan.fields["instance"]
    assert instance.dtype == np.int32
    assert len(np.unique(instance)) == 6
    chair = scan.labels == CLASS_INDEX["chair"]
    assert len(np.unique(instance[chair])) == 2
    assert read_scan(room / "Annotations").n_points == 21
    info = probe_scan(room)
    assert (info.n_points, info.has_labels, info.fields) == (21, True, ("instance",))


def test_whole_room_txt_is_unlabelled(tmp_path):
    room = _room(tmp_path, {"floor_1": 4, "table_1": 3})
    scan = read_scan(room / "office_1.txt")
    assert len(scan) == 7 and scan.labels is None and scan.rgb is not None


def test_unknown_class_names_file(tmp_path):
    room = _room(tmp_path, {"floor_1": 4, "piano_1": 3})
    with pytest.raises(ScanFormatError, match=r"piano_1.txt: unknown S3DIS class 'piano'"):
        read_scan(room)


def test_badly_named_file(tmp_path):
    room = _room(tmp_path, {"floor_1": 4, "floor": 3})
    with pytest.raises(ScanFormatError, match=r"floor.txt: annotation file names"):
        read_scan(room)


def test_bad_line_names_file_and_line(tmp_path):
    room = _room(tmp_path, {"floor_1": 4, "table_1": 3})
    path = room / "Annotations" / "table_1.txt"
    path.write_text(path.read_text() + "1.0 2.0 3.0 4 5\n")
    with pytest.raises(ScanFormatError, match=r"table_1.txt: line 4 has 5 columns"):
        read_scan(room)


def test_folder_without_annotations(tmp_path):
    (tmp_path / "stuff").mkdir()
    with pytest.raises(ScanFormatError, match="not an S3DIS room"):
        read_scan(tmp_path / "stuff")


def test_empty_annotations(tmp_path):
    (tmp_path / "r" / "Annotations").mkdir(parents=True)
    with pytest.raises(ScanFormatError, match="no <class>_<n>.txt"):
        read_scan(tmp_path / "r")


def test_max_points(tmp_path):
    room = _room(tmp_path, {"floor_1": 40, "table_1": 30})
    with pytest.raises(ScanFormatError, match="more than max_points=50"):
        read_scan(room, max_points=50)
    with pytest.raises(ScanFormatError, match="70 points, more than max_points=50"):
        probe_scan(room, max_points=50)
