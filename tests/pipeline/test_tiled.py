"""The tiled pipeline (issue 16): a scan cut into tiles gives the untiled run's labels, every
point is labelled once, segments are joined across borders, and a stop leaves nothing behind."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from jointseg.exceptions import Cancelled
from jointseg.fusion.thresholds import ClassTally
from jointseg.io import read_scan, write_scan
from jointseg.pipeline import PipelineConfig, load_predictor, run, segment_file
from jointseg.pipeline.tiled.merge import (
    MIN_LINK_POINTS,
    _gather,
    _Gathered,
    _network_outputs,
    join_segments,
    merge,
)
from jointseg.pipeline.tiled.run import cells_path, load_result, result_path, run_tile
from jointseg.pipeline.tiled.store import prepare
from jointseg.scan import Scan
from jointseg.synth import make_floor

#: a floor segmented tiled and untiled (module fixtures), and the CLI: not for `make test-fast`
pytestmark = pytest.mark.slow

POINTS = 160_000
TILE_POINTS = 50_000


@pytest.fixture(scope="module")
def floor() -> Scan:
    return make_floor(5, rooms=3, points=POINTS)


@pytest.fixture(scope="module")
def config() -> PipelineConfig:
    """The bundled network: random weights label everything alike and the vote would have
    nothing to change."""
    return PipelineConfig.model_validate(
        {
            "network": {"device": "cpu"},
            "tiles": {"max_points": TILE_POINTS, "overlap": 3.5},
            "seed": 3,
        }
    )


@pytest.fixture(scope="module")
def untiled(floor: Scan, config: PipelineConfig):
    return run(floor, config)


def chunks(scan: Scan, size: int = 37_000):
    for a in range(0, len(scan), size):
        b = min(a + size, len(scan))
        yield Scan(scan.xyz[a:b], scan.rgb[a:b] if scan.rgb is not None else None)


@pytest.fixture(scope="module")
def tiled(floor: Scan, config: PipelineConfig, tmp_path_factory: pytest.TempPathFactory):
    work = tmp_path_factory.mktemp("tiles")
    predictor = load_predictor(config.network)
    plan = prepare(
        chunks(floor),
        len(floor),
        work,
        source="floor",
        tiles=config.tiles,
        geometry=config.geometry,
        seed=config.seed,
        predictor=predictor,
    )
    for box in plan.tiles:
        run_tile(work, box.index, config, predictor=predictor, plan=plan)
    return work, plan, merge(work, config, plan=plan)


def test_plan_cuts_the_floor_into_tiles_whose_cores_hold_every_point_once(tiled) -> None:
    _, plan, merged = tiled
    assert len(plan.tiles) >= 3
    assert sum(box.core_points for box in plan.tiles) == POINTS
    assert all(box.outer_points > box.core_points for box in plan.tiles)
    assert len(merged.segment) == POINTS and merged.segment.min() >= 0


def test_network_labels_are_those_of_the_untiled_run(tiled, untiled) -> None:
    """One whole-scan crop plan, evaluated tile by tile, gives the untiled network output."""
    _, plan, merged = tiled
    assert plan.anchoring is not None and plan.anchoring.outside == 0
    agree = np.mean(merged.network_label == untiled.network_labels)
    assert agree > 0.999, agree
    np.testing.assert_allclose(merged.network_confidence, untiled.network.confidence, atol=1e-4)


def test_fused_labels_match_the_untiled_run_on_nearly_every_point(tiled, untiled) -> None:
    _, _, merged = tiled
    agree = np.mean(merged.fused_label == untiled.fused_labels)
    # each tile reads its own structure (levels and walls as seen within the tile), the one
    # part of the vote's evidence that is not the whole scan's: 0.969 here
    assert agree > 0.96, agree
    changed = np.mean(untiled.fused_labels != untiled.network_labels)
    assert changed > 0.005, "the vote changed nothing: the comparison would prove nothing"


def test_the_vote_weighs_the_whole_scans_classes_in_every_tile(
    tiled, untiled, config: PipelineConfig
) -> None:
    """The learned vote's thresholds (metric_iou 'auto') read the network's classes over the
    whole scan, not over a tile's batch: the merge tallies them as the untiled run would."""
    work, plan, _ = tiled
    gathered = _gather(work, plan, None, None)
    _network_outputs(work, plan, gathered, config)
    whole = ClassTally.of(untiled.network_labels, untiled.network.probs)
    assert gathered.tally.counts.sum() == POINTS
    np.testing.assert_allclose(gathered.tally.counts, whole.counts, atol=POINTS * 1e-3)
    np.testing.assert_allclose(gathered.tally.expected, whole.expected, rtol=1e-3, atol=1.0)
    np.testing.assert_allclose(gathered.tally.ious(), whole.ious(), atol=2e-3)


def test_segments_crossing_tile_borders_are_joined(tiled) -> None:
    """Walls and the floor span tiles: without joins there would be many more segments."""
    _, plan, merged = tiled
    assert merged.joins > 0
    assert merged.n_segments < merged.tile_segments
    # the floor plane of the whole level is one segment spanning every tile
    floor_points = merged.segment[merged.fused_label == 1]
    biggest = np.bincount(floor_points).argmax()
    owner_tiles = {
        box.index
        for box in plan.tiles
        if np.any(
            (merged.segment == biggest)
            & np.all(
                (read_xy(tiled) >= box.core_min) & (read_xy(tiled) < box.core_max),
                axis=1,
            )
        )
    }
    assert len(owner_tiles) >= 2


def read_xy(tiled) -> np.ndarray:
    work, plan, _ = tiled
    return np.fromfile(work / "points" / "xyz.f64", dtype="<f8").reshape(-1, 3)[:, :2]


def test_a_tile_run_twice_leaves_the_same_result(tiled, config: PipelineConfig) -> None:
    """(a worker killed after its tile finished, the task re-queued: the merge sees the same)"""
    work, plan, _ = tiled

    def arrays() -> dict[str, np.ndarray]:
        with np.load(result_path(work, 0)) as data:
            found = {k: data[k] for k in data.files if k != "timings"}
        with np.load(cells_path(work, 0)) as data:
            found.update({f"cells_{k}": data[k] for k in data.files})
        return found

    before = arrays()
    run_tile(work, 0, config, predictor=load_predictor(config.network), plan=plan)
    after = arrays()
    assert before.keys() == after.keys() and "point_cell" in after
    for key, values in before.items():
        assert np.array_equal(values, after[key]), key


def test_join_needs_a_mutual_majority_of_the_overlap() -> None:
    """Segment 0 (tile 0) shares most of its margin with 2 (tile 1): joined. Segment 1 grazes
    segment 3 with a few points only: kept apart."""
    n = 400
    owner_segment = np.full(n, 2, dtype=np.int64)
    owner_segment[300:] = 3
    margin_from = np.r_[np.zeros(100, np.int64), np.ones(100, np.int64)]
    margin_points = np.r_[np.arange(0, 100), np.arange(100, 200)]
    owner_segment[100:195] = 4  # segment 1's margin points are mostly owned by segment 4 ...
    owner_segment[195:200] = 3  # ... and only 5 by segment 3
    gathered = _Gathered(
        segment=owner_segment,
        labels=np.zeros(n, np.uint8),
        confidence=np.zeros(n, np.float32),
        main_plane=np.zeros(n, bool),
        structure=np.full(n, -1, np.int8),
        structure_confidence=np.zeros(n, np.float32),
        link_from=[margin_from],
        link_point=[margin_points],
        segment_tile=np.array([0, 0, 1, 1, 1], dtype=np.int32),
        entropy_sum=0.0,
        tile_timings=[],
    )
    component, joins = join_segments(gathered)
    assert component[0] == component[2]
    assert component[1] == component[4] and 95 >= MIN_LINK_POINTS
    assert component[1] != component[3]
    assert joins == 2


def test_cli_path_streams_the_output_with_every_field(
    floor: Scan, config: PipelineConfig, tmp_path: Path
) -> None:
    source = tmp_path / "floor.laz"
    write_scan(floor, source)
    output = tmp_path / "out.laz"
    done = segment_file(
        source,
        output,
        config,
        predictor=load_predictor(config.network),
        max_points=10**7,
    )
    back = read_scan(output)
    assert len(back) == POINTS
    np.testing.assert_allclose(back.xyz, read_scan(source).xyz, atol=2e-4)
    for name in ("network_label", "segment", "fused_label", "fused_confidence"):
        assert name in back.fields
    assert back.fields["fused_label"].max() <= 12
    assert done.tiles == done.report["tiles"]["count"] >= 3
    assert done.report["points"] == POINTS and done.report["input"] == str(source)
    assert list(done.report["timings_s"])[:3] == ["load_network", "prepare", "tiles"]
    assert not list(tmp_path.glob(".jointseg-tiles-*")), "the work folder was not removed"


def test_cancel_between_tiles_stops_and_leaves_no_output(
    floor: Scan, config: PipelineConfig, tmp_path: Path
) -> None:
    source = tmp_path / "floor.ply"
    write_scan(floor, source)
    output = tmp_path / "out.ply"
    stop = threading.Event()

    def progress(stage: str, fraction: float) -> None:
        if stage == "tiles" and fraction > 0:
            stop.set()  # one tile done: stop before the next

    with pytest.raises(Cancelled):
        segment_file(
            source,
            output,
            config,
            predictor=load_predictor(config.network),
            max_points=10**7,
            progress=progress,
            cancel=stop,
        )
    assert not output.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["floor.ply"]


def test_a_network_without_a_shared_crop_plan_runs_each_tile_on_its_own(
    dgcnn_random_weights: Path, tmp_path: Path
) -> None:
    """DGCNN labels blocks, not planned crops: each tile is labelled on its own and a point
    takes the output of the tile whose core holds it."""
    small = make_floor(6, rooms=2, points=12_000)
    cfg = PipelineConfig.model_validate(
        {
            "network": {
                "name": "dgcnn",
                "weights": str(dgcnn_random_weights),
                "device": "cpu",
                # small samples and no overlap between columns: a test of the tiling, not of
                # DGCNN's accuracy (40 s with the defaults on a 2-core CPU)
                "dgcnn": {"num_points": 1024, "stride": 1.0},
            },
            "tiles": {"max_points": 5_000, "overlap": 1.0},
            "fusion": {"mode": "soft"},
        }
    )
    predictor = load_predictor(cfg.network)
    plan = prepare(
        chunks(small, 5_000),
        len(small),
        tmp_path,
        source="small",
        tiles=cfg.tiles,
        geometry=cfg.geometry,
        predictor=predictor,
    )
    assert plan.anchoring is None and len(plan.tiles) >= 3
    for box in plan.tiles:
        run_tile(tmp_path, box.index, cfg, predictor=predictor, plan=plan)
    merged = merge(tmp_path, cfg, plan=plan)
    assert merged.network_confidence.min() > 0  # every point got an owner's output
    assert merged.network_label.max() <= 12 and merged.fused_label.max() <= 12
    first = load_result(tmp_path, 0)
    assert not first.network.per_cell
    assert first.network.probs is not None and first.network.labels is not None
    assert first.network.probs.shape == (len(first.core_index), 13)
    assert np.array_equal(merged.network_label[first.core_index], first.network.labels)
    # the vote's class tally adds up every tile's own outputs
    tally = _gather(tmp_path, plan, None, None).tally
    assert tally.counts.tolist() == np.bincount(merged.network_label, minlength=13).tolist()
    assert tally.expected.sum() == pytest.approx(len(small), rel=1e-3)
