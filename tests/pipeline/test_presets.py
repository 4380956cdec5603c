"""Quality presets (issue 34): fast, standard and best, as defaults under the user's settings,
end to end on synthetic scans; best's views keep tiled runs adding up to untiled ones."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jointseg.io import write_scan
from jointseg.network.choice import network_for
from jointseg.network.ensemble import EnsemblePredictor
from jointseg.network.randlanet.backend import COLOUR_FREE_WEIGHTS
from jointseg.network.registry import load
from jointseg.pipeline import PipelineConfig, load_predictor, run, segment_file
from jointseg.synth import make_floor, make_room

JOINTSEG = str(Path(sys.executable).parent / "jointseg")


def test_a_preset_fills_defaults_under_the_users_own_settings() -> None:
    fast = PipelineConfig.model_validate({"quality": "fast", "geometry": {"voxel_factor": 3.0}})
    assert fast.network.randlanet.coverage < PipelineConfig().network.randlanet.coverage
    assert fast.geometry.voxel_factor == 3.0  # the user's value wins
    assert fast.geometry.ransac_iterations < PipelineConfig().geometry.ransac_iterations
    best = PipelineConfig.model_validate({"quality": "best"})
    assert best.network.randlanet.views == 4 and best.network.ensemble
    plain = PipelineConfig()
    assert plain.quality == "standard" and plain.network.randlanet.views == 1
    assert not plain.network.ensemble
    # a dumped config validates to itself (the job table stores configs so)
    assert PipelineConfig.model_validate(json.loads(best.model_dump_json())) == best


@pytest.mark.slow
@pytest.mark.parametrize("quality", ["fast", "standard", "best"])
def test_each_preset_runs_end_to_end(tmp_path: Path, quality: str) -> None:
    source = write_scan(make_room(7, points=20_000), tmp_path / "room.ply")
    run_ = subprocess.run(
        [JOINTSEG, "segment", str(source), "-o", str(tmp_path / "out.ply"),
         "--quality", quality, "--report", str(tmp_path / "report.json")],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert run_.returncode == 0, run_.stderr
    report = json.loads((tmp_path / "report.json").read_text())
    params = report["params"]
    assert params["quality"] == quality
    assert params["network"]["views"] == (4 if quality == "best" else 1)
    assert params["network"]["networks"][0] == "randlanet"
    assert report["metrics"]["fused"]["miou"] > 0.3


@pytest.mark.slow
def test_fast_takes_fewer_crops_than_standard() -> None:
    scan = make_room(7, points=30_000)
    crops = {}
    for quality in ("fast", "standard"):
        config = PipelineConfig.model_validate({"quality": quality})
        crops[quality] = load_predictor(config.network).predict(scan, seed=0).crops
    assert crops["fast"] < crops["standard"], crops


@pytest.mark.slow
def test_an_ensemble_averages_its_members_probabilities() -> None:
    scan = make_room(2, points=20_000)
    colour = load_predictor(PipelineConfig().network)
    plain = load("randlanet", COLOUR_FREE_WEIGHTS, device="cpu", batch_size=None, params=None)
    both = EnsemblePredictor([colour, plain])
    a, b = colour.predict(scan, seed=0), plain.predict(scan, seed=0)
    mean = both.predict(scan, seed=0)
    assert both.name == "randlanet+randlanet" and mean.crops == a.crops + b.crops
    np.testing.assert_allclose(mean.probs, (a.probs + b.probs) / 2, atol=1e-6)
    assert np.array_equal(mean.labels, mean.probs.argmax(axis=1))
    assert not np.array_equal(mean.labels, a.labels)  # the second network changed something


def test_best_averages_only_colour_free_networks_on_a_scan_without_colour(
    dgcnn_random_weights: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """DGCNN (trained with colour) joins best's ensemble on a coloured scan, not on one
    without colour, where the colour-free RandLA-Net labels alone."""
    monkeypatch.setenv("JOINTSEG_DGCNN_WEIGHTS", str(dgcnn_random_weights))
    config = PipelineConfig.model_validate({"quality": "best"}).network
    predictor = load_predictor(config)
    coloured = network_for(predictor, config.choice(), usable_colour=True)
    assert [m.name for m in getattr(coloured, "members", [])] == ["randlanet", "dgcnn"]
    plain = network_for(predictor, config.choice(), usable_colour=False)
    assert not hasattr(plain, "members") and plain.name == "randlanet"
    assert plain.card.get("colour") is False


@pytest.mark.slow
def test_views_keep_tiled_network_labels_those_of_the_untiled_run(tmp_path: Path) -> None:
    floor = make_floor(5, rooms=3, points=60_000)  # tiles hold the same share as at 120 k
    source = write_scan(floor, tmp_path / "floor.ply")
    config = PipelineConfig.model_validate(
        {
            "quality": "best",  # its views, without other networks (none may be installed)
            "network": {"ensemble": False, "randlanet": {"views": 2}},
            "tiles": {"max_points": 25_000, "overlap": 3.5},
        }
    )
    predictor = load_predictor(config.network)
    untiled = run(floor, config, predictor=predictor)
    tiled = segment_file(
        source, tmp_path / "tiled.ply", config, predictor=predictor, max_points=10**7
    )
    assert tiled.tiles is not None and tiled.tiles >= 2
    # the tiled report says which preset, networks and views, as an untiled one does
    params = tiled.report["params"]
    assert params["quality"] == "best"
    assert params["network"]["networks"] == ["randlanet"] and params["network"]["views"] == 2
    assert params["network"]["views"] == untiled.params["network"]["views"]
    from jointseg.io import read_scan

    labels = read_scan(tmp_path / "tiled.ply").fields["network_label"]
    assert np.mean(labels == untiled.network_labels) > 0.999


@pytest.mark.slow
def test_fast_labels_a_tiled_floor_as_the_untiled_run_by_the_points_own_cells(
    tmp_path: Path,
) -> None:
    """fast's projection (each point from its own grid cell) is the same whether a tile or the
    whole scan made the cells, and is not the nearest sub-sampled point's everywhere."""
    floor = make_floor(6, rooms=3, points=60_000)
    source = write_scan(floor, tmp_path / "floor.ply")
    config = PipelineConfig.model_validate(
        {"quality": "fast", "tiles": {"max_points": 25_000, "overlap": 3.5}}
    )
    assert config.network.randlanet.projection == "cell"
    predictor = load_predictor(config.network)
    untiled = run(floor, config, predictor=predictor)
    tiled = segment_file(
        source, tmp_path / "tiled.ply", config, predictor=predictor, max_points=10**7
    )
    assert tiled.tiles is not None and tiled.tiles >= 2
    from jointseg.io import read_scan

    labels = read_scan(tmp_path / "tiled.ply").fields["network_label"]
    assert np.mean(labels == untiled.network_labels) > 0.999
    nearest = PipelineConfig.model_validate(
        {"quality": "fast", "network": {"randlanet": {"projection": "nearest"}}}
    )
    by_nearest = run(floor, nearest, predictor=load_predictor(nearest.network))
    same = np.mean(by_nearest.network_labels == untiled.network_labels)
    assert 0.9 < same < 1.0, same


def test_fast_sub_samples_on_a_coarser_grid_with_fewer_cells() -> None:
    from jointseg.network.anchored import anchored_cloud

    scan = make_room(8, points=300_000)  # dense enough that every 4 cm cell holds points
    cells = {}
    for quality in ("fast", "standard"):
        net = load_predictor(PipelineConfig.model_validate({"quality": quality}).network)
        cloud = anchored_cloud([(scan.xyz, scan.rgb)], net.grid_size, scan.xyz.min(axis=0))
        cells[quality] = len(cloud.xyz)
    assert PipelineConfig.model_validate({"quality": "fast"}).network.randlanet.grid == 0.05
    assert PipelineConfig().network.randlanet.grid is None  # standard: the model's own grid
    assert 0.45 < cells["fast"] / cells["standard"] < 0.85, cells
