"""The contract of geometry.segment: every point, parameters, progress, cancel, no colour."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest
from pydantic import ValidationError

from jointseg.exceptions import Cancelled, ConfigError
from jointseg.geometry import GeometryParams, segment
from jointseg.metrics import segment_purity
from jointseg.synth import make_room


@pytest.fixture(scope="module")
def scan():
    return make_room(6, points=120_000, shape="L")


def test_every_point_gets_a_segment_and_ids_are_contiguous(scan) -> None:
    result = segment(scan)
    assert result.segments.shape == (len(scan),) and result.segments.dtype == np.int32
    assert result.segments.min() == 0
    assert np.unique(result.segments).size == result.n_segments
    assert result.plane_id.shape == (len(scan),)
    assert result.main_plane.sum() == sum(p.points for p in result.planes)
    # main planes and clusters are grown apart; only crumbs too small to stand alone may join
    # a segment of the other kind
    on_plane = np.bincount(result.segments, weights=result.main_plane)
    off_plane = np.bincount(result.segments) - on_plane
    assert np.minimum(on_plane, off_plane).sum() < 0.02 * len(scan)
    assert set(result.timings) >= {"box_planes", "clustering", "region_growing"}
    plane_segments = result.plane_segments
    assert plane_segments.shape == (result.n_segments,)
    assert result.main_plane[plane_segments[result.segments]].mean() > 0.95


def test_plane_equations_are_in_the_scan_frame(scan) -> None:
    result = segment(scan)
    for i, plane in enumerate(result.planes):
        pts = scan.xyz[result.plane_id == i]
        dist = np.abs(pts @ np.asarray(plane.normal) + plane.offset)
        assert np.median(dist) < result.params.plane_distance


@pytest.mark.slow
def test_deterministic_for_a_seed(scan) -> None:
    a, b = segment(scan, seed=3), segment(scan, seed=3)
    np.testing.assert_array_equal(a.segments, b.segments)


@pytest.mark.slow
def test_hand_set_parameters_are_used(scan) -> None:
    params = GeometryParams(cluster_distance=0.05, point_colour_threshold=12.0, voxel_factor=0)
    result = segment(scan, params)
    assert result.params.cluster_distance == 0.05
    assert result.params.point_colour_threshold == 12.0
    assert result.params.voxel_factor == 0
    # derived ones are still filled in
    assert result.params.plane_distance > 0 and result.params.spacing > 0


def test_scan_without_colour_falls_back_to_geometry(scan) -> None:
    plain = replace(scan, rgb=None)
    result = segment(plain)
    assert result.params.point_colour_threshold is None
    assert result.params.colour_noise is None
    assert segment_purity(plain.labels, result.segments) >= 0.9


def test_progress_reaches_one_and_cancel_stops(scan) -> None:
    calls: list[tuple[str, float]] = []
    segment(scan, progress=lambda stage, f: calls.append((stage, f)))
    fractions = [f for _, f in calls]
    assert {s for s, _ in calls} == {"geometry"}
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    stop = threading.Event()
    stop.set()
    with pytest.raises(Cancelled):
        segment(scan, cancel=stop)


@pytest.mark.parametrize(
    "bad",
    [{"cluster_distance": -1.0}, {"ransac_iterations": 0}, {"typo_threshold": 3}],
)
def test_bad_parameters_are_rejected_at_the_edge(bad: dict) -> None:
    with pytest.raises(ValidationError):
        GeometryParams(**bad)


def test_too_few_points_is_a_clear_error(scan) -> None:
    with pytest.raises(ConfigError, match="at least 10 points"):
        segment(scan.subset(np.arange(5)))
