"""Panel data from result files: down-sampling, centring, colours, groups, cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from jointseg.classes import PALETTE
from jointseg.exceptions import ScanFormatError
from jointseg.io import read_scan, write_scan
from jointseg.scan import Scan
from tests.support.result_files import with_stray_point
from web.scene import (
    FUSED,
    NETWORK,
    RAW,
    SEGMENTS,
    TRUTH,
    SceneCache,
    group_points,
    load_scene,
    robust_box,
    segment_colours,
    voxel_downsample,
)


def test_voxel_downsample_keeps_at_most_the_limit_and_spreads_over_the_scan() -> None:
    rng = np.random.default_rng(0)
    # a 40 m x 30 m floor and a wall: surfaces, as scans are
    n, m = 150_000, 50_000
    floor = np.column_stack([rng.uniform(0, 40, n), rng.uniform(0, 30, n), np.zeros(n)])
    wall = np.column_stack([rng.uniform(0, 40, m), np.zeros(m), rng.uniform(0, 3, m)])
    xyz = np.vstack([floor, wall])
    index, voxel = voxel_downsample(xyz, 20_000)
    assert voxel is not None and voxel > 0
    assert 5_000 < index.size <= 20_000
    assert np.all(np.diff(index) > 0)  # sorted, no repeats
    # every 4 m cell of the floor keeps points: down-sampling thins evenly, it does not crop
    kept = xyz[index]
    on_floor = kept[kept[:, 2] == 0]
    cells = np.unique(np.floor(on_floor[:, :2] / 4.0).astype(int), axis=0)
    assert len(cells) == 10 * 8
    # one point per voxel: no two kept points share a cell
    keys = np.floor((kept - xyz.min(axis=0)) / voxel).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == index.size


def test_voxel_downsample_keeps_everything_under_the_limit() -> None:
    xyz = np.random.default_rng(1).normal(size=(500, 3))
    index, voxel = voxel_downsample(xyz, 500)
    assert voxel is None
    assert np.array_equal(index, np.arange(500))
    with pytest.raises(ValueError, match="max_points"):
        voxel_downsample(xyz, 0)


def test_load_scene_reads_every_label_set_centred_as_float32(results: Path) -> None:
    path = results / "labelled.ply"
    scan = read_scan(path)
    data = load_scene(path, results / "labelled.report.json")
    assert data.xyz.dtype == np.float32
    assert data.total_points == len(scan) == data.xyz.shape[0]
    assert data.voxel is None
    # centred on the room's box, its bounding box without stray points: the shown points plus
    # the centre give the scan back
    assert np.allclose(data.xyz + data.centre, scan.xyz, atol=1e-5)
    assert np.allclose(data.xyz.min(axis=0), -data.xyz.max(axis=0), atol=1e-5)
    assert np.array_equal(data.network, scan.fields["network_label"])
    assert np.array_equal(data.fused, scan.fields["fused_label"])
    assert data.truth is not None and np.array_equal(data.truth, scan.labels)
    assert np.array_equal(data.changed, data.network != data.fused)
    assert [p.key for p in data.panels] == [
        "raw",
        "network",
        "fused",
        "truth",
        "segments",
        "confidence",
        "errors",
    ]
    assert data.counts["fused"][:13].sum() == len(scan)
    assert data.report is not None and data.report["points"] == len(scan)
    assert 0 < data.spacing < 1
    # colours: the scan's own, the palette per label set
    assert np.array_equal(data.colours_of(RAW), scan.rgb)
    assert np.array_equal(data.colours_of(NETWORK), PALETTE[data.network])
    assert np.array_equal(data.colours_of(TRUTH), PALETTE[data.truth])
    assert data.labels_of(SEGMENTS) is data.fused and data.labels_of(FUSED) is data.fused


def test_load_scene_without_ground_truth_has_no_truth_panel(results: Path) -> None:
    data = load_scene(results / "unlabelled.ply", results / "unlabelled.report.json")
    assert data.truth is None
    assert TRUTH not in data.panels
    assert "truth" not in data.counts
    assert data.report is not None and data.report["metrics"] is None


def test_large_result_is_downsampled_and_still_far_from_the_origin_exact(
    results: Path, tmp_path: Path
) -> None:
    # the same result placed 5 km from the origin: float32 after centring keeps millimetres
    scan = read_scan(results / "labelled.ply")
    far = Scan(scan.xyz + [5000.0, -3000.0, 100.0], scan.rgb, scan.labels, scan.fields)
    path = write_scan(far, tmp_path / "far.ply")
    data = load_scene(path, max_points=1000)
    assert data.voxel is not None and data.xyz.shape[0] <= 1000
    assert data.total_points == len(scan)
    assert np.abs(data.xyz).max() < 20
    # every shown point is a real point of the scan, with its own labels
    full = np.round(far.xyz - data.centre, 3)
    lookup = {tuple(p): i for i, p in enumerate(full)}
    rows = [lookup[tuple(p)] for p in np.round(data.xyz.astype(np.float64), 3)]
    assert np.array_equal(data.fused, far.fields["fused_label"][rows])
    # the counts stay those of the full scan
    assert data.counts["network"].sum() == len(scan)


def test_a_stray_point_100_m_away_moves_neither_the_centre_nor_the_extent(
    results: Path, tmp_path: Path
) -> None:
    # a phone scan's stray point (a reflection, something seen through a window): the room's
    # box, its centre and the voxel size of a thinned scan stay those of the room
    with_stray = with_stray_point(read_scan(results / "labelled.ply"), (100.0, 0.0, 0.0))
    clean = load_scene(results / "labelled.ply")
    data = load_scene(write_scan(with_stray, tmp_path / "stray.ply"))
    # the box is the percentiles and a margin (at most a tenth of the room), never the 100 m
    assert np.all(np.abs(data.extent - clean.extent) <= 0.1 * clean.extent)
    assert np.all(np.abs(data.centre - clean.centre) <= 0.1 * clean.extent)
    assert np.abs(data.xyz).max() > 95  # the stray point is still shown, out of the fit
    lo, hi = robust_box(np.asarray(with_stray.xyz))
    assert np.all(hi - lo < 15)
    thinned = load_scene(tmp_path / "stray.ply", max_points=1000)
    reference = load_scene(results / "labelled.ply", max_points=1000)
    assert thinned.voxel is not None and reference.voxel is not None
    assert thinned.voxel < 1.5 * reference.voxel
    assert thinned.xyz.shape[0] > 0.6 * reference.xyz.shape[0]


def test_a_scan_that_is_not_a_result_is_refused(results: Path, tmp_path: Path) -> None:
    scan = read_scan(results / "labelled.ply")
    plain = write_scan(Scan(scan.xyz, scan.rgb), tmp_path / "plain.ply")
    with pytest.raises(ScanFormatError, match="not a jointseg result.*network_label"):
        load_scene(plain)


def test_a_broken_report_only_loses_the_scores(results: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("{not json", encoding="utf-8")
    data = load_scene(results / "labelled.ply", bad)
    assert data.report is None
    assert load_scene(results / "labelled.ply", tmp_path / "missing.json").report is None


def test_group_points_partitions_by_class_and_change() -> None:
    labels = np.array([2, 2, 5, -1, 5, 2, 40], dtype=np.int32)
    changed = np.array([0, 1, 0, 0, 0, 1, 1], dtype=bool)
    groups = group_points(labels, changed)
    assert set(groups) == {(2, False), (2, True), (5, False), (-1, False), (-1, True)}
    assert np.array_equal(groups[(2, True)], [1, 5])
    assert np.array_equal(groups[(-1, True)], [6])  # out-of-range labels count as unlabelled
    assert np.array_equal(np.sort(np.concatenate(list(groups.values()))), np.arange(7))


def test_segment_colours_are_fixed_per_segment() -> None:
    segments = np.array([7, 3, 7, 9, 3, 3])
    colours = segment_colours(segments)
    assert colours.shape == (6, 3) and colours.dtype == np.uint8
    assert np.array_equal(colours[0], colours[2])
    assert np.array_equal(colours[1], colours[5])
    assert not np.array_equal(colours[0], colours[3])
    assert np.array_equal(segment_colours(segments), colours)


def test_scene_cache_is_bounded_and_reloads_changed_files(results: Path, tmp_path: Path) -> None:
    cache = SceneCache(size=1)
    a = cache.load(results / "labelled.ply")
    assert cache.load(results / "labelled.ply") is a
    b = cache.load(results / "unlabelled.ply")
    assert len(cache) == 1 and b is not a
    assert cache.load(results / "labelled.ply") is not a  # evicted, read again
    copy = tmp_path / "copy.ply"
    copy.write_bytes((results / "labelled.ply").read_bytes())
    first = cache.load(copy)
    write_scan(read_scan(results / "unlabelled.ply"), copy)
    assert cache.load(copy) is not first


@pytest.mark.slow
def test_a_y_up_millimetre_result_is_shown_levelled_in_metres(tmp_path: Path) -> None:
    from jointseg.pipeline import PipelineConfig, segment_file
    from jointseg.pipeline.stages import load_predictor
    from jointseg.synth import make_room

    room = make_room(11, points=20_000)
    yup = Scan(room.xyz[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0]) * 1000.0, room.rgb)
    source, out, report = tmp_path / "yup.ply", tmp_path / "out.ply", tmp_path / "out.json"
    write_scan(yup, source)
    config = PipelineConfig.model_validate({"frame": {"up": "+y", "units": "mm"}})
    done = segment_file(
        source, out, config, predictor=load_predictor(config.network), max_points=10**6
    )
    report.write_text(__import__("json").dumps(done.report))
    shown = load_scene(out, report)
    # z up and metres again: the room's height along z, its footprint across x and y
    extent = shown.extent
    height = room.xyz[:, 2].max() - room.xyz[:, 2].min()
    assert abs(extent[2] - height) < 0.01
    assert np.all(extent < 20)
    # without the report the file's own frame is shown (y up, millimetres)
    assert load_scene(out).extent[1] > 1000
    # a picked point maps back to the file's own coordinates (millimetres, y up) exactly
    picked = shown.file_xyz(shown.xyz[:5])
    tree_rows = [int(np.argmin(np.linalg.norm(yup.xyz - p, axis=1))) for p in picked]
    assert np.abs(yup.xyz[tree_rows] - picked).max() < 0.5  # half a millimetre


def test_confidence_and_error_panels_colour_what_they_say(results: Path) -> None:
    from web.scene import (
        CONFIDENCE,
        CONFIDENCE_RAMP,
        ERRORS,
        NO_TRUTH_COLOUR,
        RIGHT_COLOUR,
        WRONG_COLOUR,
    )

    data = load_scene(results / "labelled.ply", results / "labelled.report.json")
    scan = read_scan(results / "labelled.ply")
    assert data.confidence is not None
    assert np.allclose(data.confidence, scan.fields["network_confidence"])
    from web.scene import confidence_colours

    # red where the network is unsure, yellow half way, green where it is sure
    ramp = CONFIDENCE_RAMP.astype(np.uint8)
    assert np.array_equal(confidence_colours(np.array([0.0, 0.5, 1.0])), ramp)
    assert np.array_equal(data.colours_of(CONFIDENCE), confidence_colours(data.confidence))
    errors = data.colours_of(ERRORS)
    assert data.truth is not None
    wrong = (data.fused != data.truth) & (data.truth >= 0)
    assert wrong.any() and (~wrong).any()
    assert (errors[wrong] == WRONG_COLOUR).all()
    assert (errors[~wrong & (data.truth >= 0)] == RIGHT_COLOUR).all()
    assert (errors[data.truth < 0] == NO_TRUTH_COLOUR).all()
    # without ground truth there is no error map, and the confidence panel stays
    bare = load_scene(results / "unlabelled.ply")
    assert ERRORS not in bare.panels and CONFIDENCE in bare.panels
