"""A tiled run opens its input several times; the whole-file facts of a LAZ or PLY are gathered
once per file, and again when the file changes."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jointseg.io import write_scan
from jointseg.io.stream import open_chunks
from jointseg.scan import Scan


def _counting(monkeypatch, module: str, name: str) -> list[int]:
    import importlib

    mod = importlib.import_module(module)
    calls: list[int] = []
    real = getattr(mod, name)

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(mod, name, counted)
    return calls


def _scan(n: int, seed: int) -> Scan:
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(0, 5, (n, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    return Scan(xyz, rgb, rng.integers(0, 13, n).astype(np.int32))


def _read_all(path: Path) -> Scan:
    with open_chunks(path, max_points=10**6) as chunks:
        parts = list(chunks.chunks(2_000))
    return Scan(
        np.concatenate([p.xyz for p in parts]),
        np.concatenate([p.rgb for p in parts]),
        np.concatenate([p.labels for p in parts]),
    )


def test_a_laz_is_passed_over_once_until_it_changes(tmp_path: Path, monkeypatch) -> None:
    path = tmp_path / "floor.laz"
    write_scan(_scan(5_000, 0), path)
    passes = _counting(monkeypatch, "jointseg.io.formats.las.stream", "_las_facts")
    first = _read_all(path)
    second = _read_all(path)
    assert len(passes) == 1
    np.testing.assert_array_equal(first.rgb, second.rgb)
    np.testing.assert_array_equal(first.labels, second.labels)
    # rewritten with other colours: gathered again, and the chunks follow the new file
    write_scan(_scan(5_000, 1), path)
    os.utime(path, ns=(1, 1))  # another mtime even on a coarse clock
    third = _read_all(path)
    assert len(passes) == 2
    assert not np.array_equal(first.rgb, third.rgb)
