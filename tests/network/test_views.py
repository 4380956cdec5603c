"""Test-time views: turned and mirrored copies of each crop, averaged."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from jointseg.network.randlanet.views import in_view, view_matrix
from jointseg.pipeline import PipelineConfig, load_predictor
from jointseg.synth import make_room


def test_views_turn_and_mirror_the_horizontal_coordinates_only() -> None:
    assert view_matrix(0, 4) is None
    for view in range(1, 4):
        m = view_matrix(view, 4)
        assert m is not None and torch.allclose(m @ m.T, torch.eye(2), atol=1e-6)
        assert torch.linalg.det(m).item() == pytest.approx(-1.0 if view % 2 else 1.0)
    features = torch.randn(1, 50, 6)
    coords = [features[:, :, :3].clone(), features[:, :25, :3].clone()]
    f, c = in_view(features, coords, 1, 4)
    assert torch.equal(f[..., 2:], features[..., 2:])  # height and colour untouched
    assert not torch.allclose(f[..., :2], features[..., :2])
    # distances within the crop, so its neighbours, do not change
    exact = "donot_use_mm_for_euclid_dist"
    turned = torch.cdist(c[0], c[0], compute_mode=exact)
    assert torch.allclose(turned, torch.cdist(coords[0], coords[0], compute_mode=exact), atol=1e-5)


@pytest.mark.slow
def test_a_scan_turned_by_90_degrees_gets_the_same_labels_on_most_points() -> None:
    scan = make_room(3, points=30_000)
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    turned = replace(scan, xyz=(scan.xyz @ turn.T).astype(scan.xyz.dtype))
    config = PipelineConfig.model_validate({"network": {"randlanet": {"views": 4}}})
    predictor = load_predictor(config.network)
    plain = load_predictor(PipelineConfig().network).predict(scan, seed=0)
    a, b = predictor.predict(scan, seed=0), predictor.predict(turned, seed=0)
    assert a.crops == plain.crops  # views share each crop, not add crops
    assert not np.allclose(a.probs, plain.probs)  # the views are averaged in
    assert np.mean(a.labels == b.labels) >= 0.85
    assert np.mean(a.labels == scan.labels) >= np.mean(plain.labels == scan.labels) - 0.02
