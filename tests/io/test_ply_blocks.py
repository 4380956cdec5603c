"""Chosen columns and rows of a binary PLY, read block by block."""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from jointseg.io import ScanFormatError
from jointseg.io.formats.ply.blocks import open_vertex_blocks


def _write(path, n, *, text=False, byte_order="<", faces_first=False):
    rng = np.random.default_rng(0)
    data = np.empty(n, dtype=[("x", "f8"), ("y", "f8"), ("z", "f4"), ("label", "i4")])
    for name in ("x", "y", "z"):
        data[name] = rng.random(n)
    data["label"] = rng.integers(-1, 13, n)
    elements = [PlyElement.describe(data, "vertex")]
    if faces_first:
        faces = np.array([([0, 1, 2],)], dtype=[("vertex_indices", "i4", (3,))])
        elements.insert(0, PlyElement.describe(faces, "face"))
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))
    return path, data


@pytest.mark.parametrize("order", ["<", ">"])
def test_blocks_cover_every_vertex_and_take_picks_rows_and_columns(tmp_path, order) -> None:
    path, data = _write(tmp_path / "a.ply", 1_000, byte_order=order)
    source = open_vertex_blocks(path)
    assert source is not None and source.count == 1_000
    assert source.names == ["x", "y", "z", "label"]
    labels, picked = [], []
    for block in source.blocks(block_bytes=24 * 64 + 5):  # 64 records a block
        assert len(block.records) <= 64
        labels.append(block.column("label").copy())
        rows = np.arange(0, len(block.records), 7)
        part = block.take(rows, ["z", "label"])
        assert set(part) == {"z", "label"}
        picked.append(part["z"].astype(np.float64))
    assert np.array_equal(np.concatenate(labels), data["label"])
    want = np.concatenate([data["z"][s : s + 64][::7] for s in range(0, 1_000, 64)])
    assert np.array_equal(np.concatenate(picked), want)


def test_ascii_and_list_elements_first_are_left_to_the_full_reader(tmp_path) -> None:
    assert open_vertex_blocks(_write(tmp_path / "t.ply", 10, text=True)[0]) is None
    assert open_vertex_blocks(_write(tmp_path / "f.ply", 10, faces_first=True)[0]) is None


def test_a_truncated_file_is_refused_before_any_block(tmp_path) -> None:
    path, _ = _write(tmp_path / "a.ply", 100)
    path.write_bytes(path.read_bytes()[:-10])
    source = open_vertex_blocks(path)
    assert source is not None
    with pytest.raises(ScanFormatError, match="truncated PLY: the header declares 100 vertices"):
        source.blocks(block_bytes=1 << 20)
