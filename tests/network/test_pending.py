"""A network loading in a thread (jointseg.network.pending): the run waits for it only where it
is needed, gives the labels a loaded network gives, and a failed load fails the run clearly."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from jointseg.exceptions import ConfigError
from jointseg.network.choice import Choice, network_for
from jointseg.network.judge import crop_labeller
from jointseg.network.pending import PendingPredictor, resolve
from jointseg.network.registry import load, locate
from jointseg.pipeline.config import PipelineConfig
from jointseg.pipeline.stages import run
from jointseg.synth import make_room


def _held(release: threading.Event, weights: Path) -> PendingPredictor:
    """A pending network whose load waits for ``release``."""
    return PendingPredictor(lambda: None, lambda: (release.wait(30), load(weights=weights))[1])


def test_a_colour_scan_chooses_its_network_without_waiting_for_the_load(random_weights) -> None:
    release = threading.Event()
    pending = _held(release, random_weights)
    try:
        chosen = network_for(pending, Choice(), usable_colour=True)
        judge = crop_labeller(chosen)
        assert chosen is pending and judge is not None
        assert not pending.ready  # neither the choice nor the judge's making waited
    finally:
        release.set()
    assert resolve(pending).card == load(weights=random_weights).card
    assert pending.ready and pending.load_s > 0


def test_a_run_with_a_pending_network_gives_the_loaded_networks_labels(random_weights) -> None:
    scan = make_room(5, points=20_000)
    config = PipelineConfig()
    loaded = run(scan, config, predictor=load(weights=random_weights))
    release = threading.Event()
    pending = _held(release, random_weights)
    threading.Timer(0.5, release.set).start()  # loads while the frame and geometry run
    later = run(scan, config, predictor=pending)
    np.testing.assert_array_equal(later.network_labels, loaded.network_labels)
    np.testing.assert_array_equal(later.fused_labels, loaded.fused_labels)
    np.testing.assert_array_equal(later.segments, loaded.segments)
    assert later.timings["network_wait"] >= 0.0
    assert later.params["network"] == loaded.params["network"]


def test_a_failed_load_fails_the_run_with_its_own_error(tmp_path: Path) -> None:
    bad = tmp_path / "broken.pt"
    bad.write_bytes(b"not a checkpoint")
    pending = PendingPredictor(lambda: None, lambda: load(weights=bad))
    with pytest.raises(ConfigError, match="broken.pt"):
        run(make_room(1, points=5_000), PipelineConfig(), predictor=pending)
    with pytest.raises(ConfigError, match="broken.pt"):  # and again to a later user
        pending.get()


def test_missing_weights_are_refused_before_any_load(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no weights for 'randlanet' at"):
        locate("randlanet", tmp_path / "none.pt")
    with pytest.raises(ConfigError, match="unknown network 'nope'"):
        locate("nope")
