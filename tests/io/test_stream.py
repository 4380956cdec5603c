"""Chunked reading and writing (jointseg.io.stream): chunks concatenate to read_scan's scan, a
file written chunk by chunk is write_scan's file, failures leave nothing behind, and memory
follows the chunk size."""

from __future__ import annotations

import logging
import os
import tracemalloc
from pathlib import Path

import laspy
import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from jointseg.exceptions import ConfigError
from jointseg.io import ScanFormatError, chunks, read_scan, write_scan
from jointseg.io.formats import FORMATS
from jointseg.io.stream import ScanChunks, open_chunks, open_writer
from jointseg.scan import Scan
from jointseg.synth import make_room
from tests.support.scans import random_scan

SIZES = [7, 1000, 10**6]


@pytest.fixture(scope="module")
def room() -> Scan:
    """A small synthetic room: colour, labels and the fields instance, scanner, range."""
    return make_room(0, points=2500)


def _variants(room: Scan) -> dict[str, Scan]:
    bare = Scan(room.xyz)
    return {
        "full": room,
        "bare": bare,
        "labels_only": Scan(room.xyz, labels=room.labels),
        "colour_only": Scan(room.xyz, rgb=room.rgb, fields={"range": room.fields["range"]}),
        "many_fields": random_scan(1500, seed=4).with_fields(
            normal=np.random.default_rng(1).normal(size=(1500, 3)),
            flag=np.arange(1500) % 3 == 0,
        ),
        # a pipeline's result: LAS classification holds it, the labels go to extra bytes
        "result": room.with_fields(
            fused_label=(np.arange(len(room)) % 13).astype(np.int32),
            stray=(np.arange(len(room)) % 41 == 0).astype(np.uint8),
        ),
    }


def assert_same_scan(got: Scan, want: Scan) -> None:
    """Same arrays, dtypes, fields (in order) and source format."""
    assert got.source_format == want.source_format
    for name in ("xyz", "rgb", "labels"):
        a, b = getattr(got, name), getattr(want, name)
        assert (a is None) == (b is None), name
        if b is not None:
            assert a.dtype == b.dtype, name
            np.testing.assert_array_equal(a, b, err_msg=name)
    assert list(got.fields) == list(want.fields)
    for name, values in want.fields.items():
        assert got.fields[name].dtype == values.dtype, name
        np.testing.assert_array_equal(got.fields[name], values, err_msg=name)


def _join(chunks: list[Scan]) -> Scan:
    def cat(parts):  # keeping the chunks' dtype (concatenate makes byte order native)
        return None if parts[0] is None else np.concatenate(parts).astype(parts[0].dtype)

    return Scan(
        xyz=cat([c.xyz for c in chunks]),
        rgb=cat([c.rgb for c in chunks]),
        labels=cat([c.labels for c in chunks]),
        fields={k: cat([c.fields[k] for c in chunks]) for k in chunks[0].fields},
        source_format=chunks[0].source_format,
    )


def read_chunked(path: Path, size: int, *, streams: bool | None = None) -> Scan:
    """Read ``path`` in chunks of ``size``, checking the chunk sizes, and join them."""
    with open_chunks(path) as source:
        if streams is not None:
            assert source.streams is streams
        chunks = list(source.chunks(size))
        assert sum(len(c) for c in chunks) == source.count
        assert all(len(c) == size for c in chunks[:-1]) and 0 < len(chunks[-1]) <= size
        assert all(c.source_format == source.format for c in chunks)
    return _join(chunks)


# ---------------------------------------------------------------- reading


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize(
    "variant", ["full", "bare", "labels_only", "colour_only", "many_fields", "result"]
)
@pytest.mark.parametrize("ext", [".las", ".laz", ".ply"])
def test_chunks_join_to_read_scan(tmp_path, room, ext, variant, size):
    path = write_scan(_variants(room)[variant], tmp_path / f"s{ext}")
    assert_same_scan(read_chunked(path, size, streams=True), read_scan(path))


@pytest.mark.parametrize("stride", [1, 7, 1000, 10**6])
@pytest.mark.parametrize("variant", ["full", "bare", "result"])
@pytest.mark.parametrize("ext", [".las", ".laz", ".ply", ".pcd"])
def test_a_sample_is_every_stride_th_point_of_the_chunks(tmp_path, room, ext, variant, stride):
    """The LAS reader's own sample (only the coordinate and colour layers of a LAZ read, only
    the sampled records converted) is the chunks' points 0, stride, 2 stride, ..."""
    path = write_scan(_variants(room)[variant], tmp_path / f"s{ext}")
    whole = read_scan(path)
    with open_chunks(path) as source:
        got = source.sample(stride, 300)  # chunks of 300: the sample crosses their borders
    np.testing.assert_array_equal(got.xyz, whole.xyz[::stride])
    assert (got.rgb is None) == (whole.rgb is None)
    if whole.rgb is not None:
        np.testing.assert_array_equal(got.rgb, whole.rgb[::stride])
    assert got.labels is None and not got.fields
    assert got.source_format == whole.source_format
    assert list(got.meta) == list(whole.meta)
    for key, value in whole.meta.items():
        np.testing.assert_equal(got.meta[key], value, err_msg=key)


@pytest.mark.parametrize("variant", ["full", "bare", "result"])
@pytest.mark.parametrize("ext", [".las", ".laz", ".ply", ".txt"])
def test_coordinates_are_the_chunks_xyz(tmp_path, room, ext, variant):
    """A pass over the coordinates alone (a LAZ's other layers not read) gives the chunks' xyz,
    chunk for chunk."""
    path = write_scan(_variants(room)[variant], tmp_path / f"s{ext}")
    with open_chunks(path) as source:
        got = list(source.coordinates(700))
        want = [c.xyz for c in source.chunks(700)]
    assert [len(g) for g in got] == [len(w) for w in want]
    for g, w in zip(got, want, strict=True):
        assert g.dtype == w.dtype
        np.testing.assert_array_equal(g, w)


def test_a_sample_stride_must_be_a_positive_integer(tmp_path, room):
    path = write_scan(room, tmp_path / "s.laz")
    with open_chunks(path) as source:
        for bad in (0, -3, 2.5, True):
            with pytest.raises(ConfigError, match="stride"):
                source.sample(bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="closed"):
        source.sample(3)


@pytest.mark.parametrize("ext", [".pcd", ".npz", ".txt"])
def test_other_formats_fall_back_to_slices(tmp_path, room, ext):
    path = write_scan(room, tmp_path / f"s{ext}")
    for size in (7, 1000, 10**6):
        assert_same_scan(read_chunked(path, size, streams=False), read_scan(path))


def _ply(path: Path, n: int, *, text: bool = False, order: str = "=", colour="u2", label="i4"):
    """A third-party PLY: 16-bit colour that is dark in the first 100 vertices, odd labels (40)
    only after vertex 500."""
    rng = np.random.default_rng(2)
    data = np.empty(
        n,
        dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", colour), ("green", colour)]
        + [("blue", colour), ("class", label), ("nx", "f4")],
    )
    for axis in "xyz":
        data[axis] = rng.random(n)
    top = 65535 if colour == "u2" else 1.0
    for c in ("red", "green", "blue"):
        data[c] = rng.uniform(0, top, n).astype(colour)
        data[c][:100] = rng.uniform(0, top / 300, 100).astype(colour)
    data["class"] = np.arange(n) % 13
    data["class"][500::97] = 40
    data["nx"] = rng.normal(size=n)
    PlyData([PlyElement.describe(data, "vertex")], text=text, byte_order=order).write(str(path))
    return path


@pytest.mark.parametrize(
    ("text", "order", "streams"),
    [(False, "<", True), (False, ">", True), (True, "=", False)],
    ids=["little", "big", "ascii"],
)
@pytest.mark.parametrize(("colour", "label"), [("u2", "i4"), ("f4", "f8")])
def test_ply_whole_file_decisions(tmp_path, text, order, streams, colour, label, caplog):
    path = _ply(tmp_path / "t.ply", 1200, text=text, order=order, colour=colour, label=label)
    whole = read_scan(path)
    assert "raw_label" in whole.fields and whole.rgb is not None
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        got = read_chunked(path, 97, streams=streams)
    assert_same_scan(got, whole)
    assert caplog.text.count("outside the S3DIS classes") == 1  # once per file, not per chunk


def _las(
    path: Path,
    n: int = 3000,
    *,
    point_format: int = 3,
    rgb: str = "16bit_dark_start",
    cls: np.ndarray | None = None,
    intensity: np.ndarray | None = None,
) -> Path:
    """A LAS/LAZ file as another program writes it (not marked by jointseg)."""
    rng = np.random.default_rng(5)
    header = laspy.LasHeader(
        point_format=point_format, version="1.4" if point_format > 5 else "1.2"
    )
    header.scales = np.full(3, 0.001)
    header.offsets = np.array([500.0, 20.0, 0.0])
    header.add_extra_dims([laspy.ExtraBytesParams(name="ring", type=np.uint8)])
    las = laspy.LasData(header)
    las.x, las.y, las.z = (rng.uniform(0, 30, n) + o for o in header.offsets)
    if "red" in header.point_format.dimension_names:
        values = rng.integers(0, 256, (n, 3))
        if rgb == "16bit_dark_start":
            values = values * 257
            values[:1000] //= 300  # the first chunks alone look like 8-bit colour
        elif rgb == "8bit_dark_start":
            values[:1000] //= 16
        for i, c in enumerate(("red", "green", "blue")):
            las[c] = values[:, i]
    if cls is not None:
        las.classification = cls
    if intensity is not None:
        las.intensity = intensity
    las.ring = np.arange(n) % 32
    las.write(str(path))
    return path


@pytest.mark.parametrize("ext", [".las", ".laz"])
@pytest.mark.parametrize("point_format", [3, 7])
@pytest.mark.parametrize("rgb", ["16bit_dark_start", "8bit_dark_start"])
def test_las_colour_decision_is_whole_file(tmp_path, ext, point_format, rgb):
    path = _las(tmp_path / f"c{ext}", point_format=point_format, rgb=rgb)
    whole = read_scan(path)
    got = read_chunked(path, 999, streams=True)
    assert_same_scan(got, whole)
    assert got.rgb is not None and got.rgb[1000:].max() > 200  # bright after the dark start


def _late(n: int, value: int, *, at: int = 2000, every: int = 1) -> np.ndarray:
    """Zeros, then ``value`` at every ``every``-th point from point ``at``."""
    out = np.zeros(n, dtype=np.int64)
    out[at::every] = value
    return out


@pytest.mark.parametrize("ext", [".las", ".laz"])
@pytest.mark.parametrize("point_format", [1, 6])
@pytest.mark.parametrize(
    ("cls", "intensity"),
    [
        (_late(3000, 5), _late(3000, 900)),  # classified and intensity only late: kept for all
        (_late(3000, 17, every=50) + _late(3000, 2, at=0, every=7), None),
        (None, None),  # never classified, no intensity: neither labels nor intensity
    ],
    ids=["late", "odd_late", "never"],
)
def test_las_label_and_intensity_decisions_are_whole_file(
    tmp_path, ext, point_format, cls, intensity, caplog
):
    path = _las(
        tmp_path / f"l{ext}", point_format=point_format, rgb="none", cls=cls, intensity=intensity
    )
    whole = read_scan(path)
    assert (whole.labels is None) == (cls is None)
    assert ("intensity" in whole.fields) == (intensity is not None)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        got = read_chunked(path, 700, streams=True)
    assert_same_scan(got, whole)
    odd = cls is not None and (cls > 12).any()
    assert ("classification" in got.fields) == odd
    assert caplog.text.count("outside the S3DIS classes") == int(odd)


def test_chunks_twice_interleaved_and_closed(tmp_path, room):
    path = write_scan(room, tmp_path / "r.laz")
    with open_chunks(path) as source:
        first = source.chunks(1000)
        second = source.chunks(1000)
        a, b = next(first), next(second)
        np.testing.assert_array_equal(a.xyz, b.xyz)
        np.testing.assert_array_equal(next(first).xyz, next(second).xyz)
        again = list(source.chunks(600))
        assert sum(len(c) for c in again) == len(room)
    assert list(first) == []  # closing the source stopped the running iterations
    with pytest.raises(ValueError, match="closed"):
        source.chunks()


@pytest.mark.parametrize("size", [0, -3, 2.5, True])
def test_chunk_size_must_be_a_positive_integer(tmp_path, room, size):
    with open_chunks(write_scan(room, tmp_path / "r.ply")) as source, pytest.raises(ConfigError):
        source.chunks(size)


def _error(call) -> str:
    with pytest.raises(ScanFormatError) as info:
        call()
    return str(info.value)


@pytest.mark.parametrize("ext", [".las", ".laz", ".ply", ".pcd"])
def test_bad_files_give_read_scans_errors_at_open(tmp_path, room, ext):
    path = write_scan(room, tmp_path / f"r{ext}")
    message = _error(lambda: open_chunks(path, max_points=100))
    assert message == _error(lambda: read_scan(path, max_points=100))
    assert "max_points=100" in message and str(path) in message
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])  # truncated (a corrupt LAZ stream)
    assert str(path) in _error(lambda: open_chunks(path))
    if ext != ".laz":
        assert _error(lambda: open_chunks(path)) == _error(lambda: read_scan(path))
    path.write_bytes(b"not a scan at all" * 10)
    assert _error(lambda: open_chunks(path)) == _error(lambda: read_scan(path))
    assert "not found" in _error(lambda: open_chunks(tmp_path / f"missing{ext}"))


def test_non_finite_coordinates_name_the_point_in_the_file(tmp_path, room):
    data = np.zeros(50, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    data["x"][37] = np.nan
    path = tmp_path / "nan.ply"
    PlyData([PlyElement.describe(data, "vertex")]).write(str(path))
    with open_chunks(path) as source:
        chunks = source.chunks(10)
        assert len(next(chunks)) == 10
        with pytest.raises(ScanFormatError, match=r"point 37 .*among points 30\.\.39"):
            list(chunks)


def test_file_changed_after_open_is_refused(tmp_path, room):
    path = write_scan(room, tmp_path / "r.ply")
    with open_chunks(path) as source:
        write_scan(random_scan(100), path)
        with pytest.raises(ScanFormatError, match="changed since it was opened"):
            next(source.chunks())


def test_empty_las_is_refused_like_read_scan(tmp_path):
    path = tmp_path / "empty.las"
    laspy.LasData(laspy.LasHeader(point_format=3, version="1.2")).write(str(path))
    assert _error(lambda: open_chunks(path)) == _error(lambda: read_scan(path))


# ---------------------------------------------------------------- writing


def _bounds(scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    return scan.xyz.min(axis=0), scan.xyz.max(axis=0)


def write_chunked(scan: Scan, path: Path, size: int) -> Path:
    """Write ``scan`` through open_writer in chunks of ``size`` (the first chunk as ``like``)."""
    parts = [scan.subset(np.arange(i, min(i + size, len(scan)))) for i in range(0, len(scan), size)]
    with open_writer(path, count=len(scan), like=parts[0], bounds=_bounds(scan)) as out:
        for part in parts:
            out.write(part)
    return path


def _las_points(path: Path) -> tuple[laspy.LasHeader, np.ndarray]:
    las = laspy.read(str(path))
    return las.header, las.points.array


@pytest.mark.parametrize("size", [7, 1000])
@pytest.mark.parametrize("variant", ["full", "bare", "labels_only", "many_fields", "result"])
@pytest.mark.parametrize("ext", [".las", ".laz", ".ply", ".pcd", ".npz"])
def test_chunked_writing_gives_write_scans_file(tmp_path, room, ext, variant, size):
    scan = _variants(room)[variant]
    if variant == "many_fields":
        # whole numbers in 0..65535: the standard LAS intensity, chosen from the first chunk
        scan = scan.with_fields(intensity=(np.arange(len(scan)) % 5000).astype(np.int32))
    got = write_chunked(scan, tmp_path / f"chunked{ext}", size)
    want = write_scan(scan, tmp_path / f"whole{ext}")
    assert_same_scan(read_scan(got), read_scan(want))
    if ext in (".las", ".laz"):
        (h1, p1), (h2, p2) = _las_points(got), _las_points(want)
        np.testing.assert_array_equal(p1, p2)  # every point record, bit for bit
        for attr in ("scales", "offsets", "mins", "maxs"):
            np.testing.assert_array_equal(getattr(h1, attr), getattr(h2, attr), err_msg=attr)
        assert (h1.point_format, h1.point_count) == (h2.point_format, h2.point_count)
        assert [v.description for v in h1.vlrs] == [v.description for v in h2.vlrs]
    else:
        assert got.read_bytes() == want.read_bytes()


def test_read_chunks_then_write_chunks_round_trip(tmp_path, room):
    source_path = write_scan(room, tmp_path / "in.laz")
    with open_chunks(source_path) as source:
        like = next(source.chunks(10))
        whole = read_scan(source_path)
        with open_writer(
            tmp_path / "out.ply", count=source.count, like=like, bounds=_bounds(whole)
        ) as out:
            for chunk in source.chunks(333):
                out.write(chunk)
    assert_same_scan(
        read_scan(tmp_path / "out.ply"), read_scan(write_scan(whole, tmp_path / "w.ply"))
    )


class Boom(RuntimeError):
    pass


@pytest.mark.parametrize("ext", [".las", ".laz", ".ply", ".pcd"])
def test_failure_inside_the_block_leaves_nothing(tmp_path, room, ext):
    target = tmp_path / f"out{ext}"
    with pytest.raises(Boom):
        with open_writer(target, count=len(room), like=room, bounds=_bounds(room)) as out:
            out.write(room.subset(np.arange(1000)))
            raise Boom
    assert os.listdir(tmp_path) == []
    # an existing file at the target is left as it was
    target.write_bytes(b"old")
    with pytest.raises(Boom):
        with open_writer(target, count=len(room), like=room, bounds=_bounds(room)) as out:
            out.write(room.subset(np.arange(1000)))
            raise Boom
    assert os.listdir(tmp_path) == [target.name] and target.read_bytes() == b"old"


@pytest.mark.parametrize("ext", [".laz", ".ply", ".npz"])
def test_wrong_point_count_is_refused(tmp_path, room, ext):
    target = tmp_path / f"out{ext}"
    with pytest.raises(ValueError, match=r"1,000 points were written but count=2,500"):
        with open_writer(target, count=len(room), like=room, bounds=_bounds(room)) as out:
            out.write(room.subset(np.arange(1000)))
    with pytest.raises(ValueError, match="would exceed count=2,500"):
        with open_writer(target, count=len(room), like=room, bounds=_bounds(room)) as out:
            out.write(room)
            out.write(room.subset(np.arange(1)))
    assert os.listdir(tmp_path) == []


def test_chunks_must_match_like(tmp_path, room):
    with open_writer(tmp_path / "o.las", count=len(room), like=room, bounds=_bounds(room)) as out:
        for bad in (
            Scan(room.xyz, room.rgb, room.labels, {}),
            room.with_fields(range=room.fields["range"].astype(np.float64)),
            Scan(room.xyz, None, room.labels, room.fields),
        ):
            with pytest.raises(ValueError, match="differs from `like`"):
                out.write(bad)
        out.write(room)
    with pytest.raises(ValueError, match="outside"):
        out.write(room)


def test_values_that_do_not_fit_the_layout_from_like_are_refused(tmp_path, room):
    small = room.with_fields(intensity=np.arange(len(room), dtype=np.int32))
    big = room.with_fields(intensity=np.arange(len(room), dtype=np.int32) * 100)
    with pytest.raises(ScanFormatError, match="standard intensity dimension"):
        with open_writer(
            tmp_path / "o.las", count=2 * len(room), like=small, bounds=_bounds(room)
        ) as out:
            out.write(small)
            out.write(big)
    small = room.with_fields(id=np.arange(len(room), dtype=np.int64))
    with pytest.raises(ScanFormatError, match="cannot hold exactly"):
        with open_writer(
            tmp_path / "o.ply", count=2 * len(room), like=small, bounds=_bounds(room)
        ) as out:
            out.write(small)
            out.write(small.with_fields(id=small.fields["id"] + 2**40))
    far = Scan(room.xyz + 1e6, room.rgb, room.labels, room.fields)
    with pytest.raises(ScanFormatError, match="32-bit integers"):
        with open_writer(
            tmp_path / "o.laz", count=len(room), like=room, bounds=_bounds(room)
        ) as out:
            out.write(far)
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(
    ("kwargs", "error"),
    [
        ({"count": -1}, ValueError),
        ({"bounds": (np.zeros(2), np.ones(2))}, ValueError),
        ({"bounds": (np.ones(3), np.zeros(3))}, ValueError),
        ({"path": "out.e57"}, ScanFormatError),
        ({"path": "missing/out.las"}, ScanFormatError),
    ],
)
def test_open_writer_checks_its_arguments(tmp_path, room, kwargs, error):
    args = {"count": len(room), "like": room, "bounds": _bounds(room), **kwargs}
    path = tmp_path / args.pop("path", "out.las")
    with pytest.raises(error):
        open_writer(path, **args)


# ---------------------------------------------------------------- memory


def _peak_bytes(work) -> int:
    tracemalloc.start()
    try:
        work()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_chunked_reading_and_writing_memory_follows_the_chunk(tmp_path, monkeypatch):
    """numpy reports its buffers to tracemalloc, so peaks are deterministic (no timing)."""
    monkeypatch.setattr(chunks, "PASS_POINTS", 10_000)  # the first pass: 250 k per step
    scan = random_scan(200_000, seed=9)
    path = write_scan(scan, tmp_path / "big.laz")
    del scan

    def chunked() -> None:
        with open_chunks(path) as source:
            like = next(source.chunks(10))
            lo = np.full(3, np.inf)
            hi = -lo
            for chunk in source.chunks(10_000):
                lo, hi = (
                    np.minimum(lo, chunk.xyz.min(axis=0)),
                    np.maximum(hi, chunk.xyz.max(axis=0)),
                )
            with open_writer(
                tmp_path / "out.laz", count=source.count, like=like, bounds=(lo, hi)
            ) as out:
                for chunk in source.chunks(10_000):
                    out.write(chunk)

    def whole() -> None:
        write_scan(read_scan(path), tmp_path / "whole.laz")

    chunked_peak, whole_peak = _peak_bytes(chunked), _peak_bytes(whole)
    assert chunked_peak * 8 < whole_peak, (chunked_peak, whole_peak)
    assert chunked_peak < 30 * 2**20


def test_scan_chunks_is_exported_type(tmp_path, room):
    assert isinstance(open_chunks(write_scan(room, tmp_path / "r.npz")), ScanChunks)


def test_the_format_table_names_what_streams():
    """open_chunks/open_writer dispatch through the Format records; the rest fall back."""
    assert {n for n, f in FORMATS.items() if f.open_chunks is not None} == {"las", "laz", "ply"}
    assert {n for n, f in FORMATS.items() if f.open_writer is not None} == {"las", "laz", "ply"}
    assert all(f.write is not None for f in FORMATS.values() if f.open_writer is not None)
