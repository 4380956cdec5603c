"""Learning from corrections (issue 66): a class the bundled network misses is learnt from a
user's segment clicks, and a re-scan of the room comes out with it; bad inputs are refused
before anything is written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.adapt.head import AdaptParams
from jointseg.adapt.learn import Corrected, adapt
from jointseg.exceptions import ConfigError
from jointseg.io import write_scan
from jointseg.metrics import evaluate
from jointseg.network.checkpoint import load_checkpoint
from jointseg.pipeline import load_predictor, run
from jointseg.pipeline.config import PipelineConfig
from jointseg.synth import make_room
from tests.adapt.conftest import BEAM, ROOM, iou
from tests.support.cli import run_cli

FAST = AdaptParams(steps=150, replay_rooms=1)


def test_the_adapted_model_learns_a_class_the_bundled_one_misses(
    corrected: Path, tmp_path: Path
) -> None:
    predictor = load_predictor(PipelineConfig().network)
    out = tmp_path / "site.pt"
    done = adapt([Corrected(corrected, "room 4", 1)], out, predictor=predictor,
                 choice=PipelineConfig().network.choice(), params=FAST)  # fmt: skip
    assert done.losses[-1] < done.losses[0]
    card = load_checkpoint(out)[1]
    scans = card["adapted"]["scans"]
    assert [s["name"] for s in scans] == ["room 4"] and scans[0]["version"] == 1
    assert scans[0]["classes"] == {"beam": scans[0]["corrected_points"]}
    # a re-scan of the room (another scanner pass: other points of the same surfaces)
    again = make_room(ROOM, points=30_000)
    assert again.labels is not None
    bundled = run(again, PipelineConfig(seed=0))
    adapted = run(
        again, PipelineConfig.model_validate({"seed": 0, "network": {"weights": str(out)}})
    )
    assert iou(again.labels, adapted.network.labels, BEAM) > 0.3
    assert (
        iou(again.labels, adapted.fusion.labels, BEAM)
        > iou(again.labels, bundled.fusion.labels, BEAM) + 0.3
    )
    # what nobody corrected keeps its labels: the other classes' points mostly unchanged
    others = (again.labels != BEAM) & (again.labels >= 0)
    same = np.mean(adapted.network.labels[others] == bundled.network.labels[others])
    assert same > 0.9
    assert (
        evaluate(again.labels, adapted.fusion.labels).miou
        > evaluate(again.labels, bundled.fusion.labels).miou
    )


def test_results_without_corrections_or_not_results_are_refused(
    corrected: Path, tmp_path: Path
) -> None:
    predictor = load_predictor(PipelineConfig().network)
    choice = PipelineConfig().network.choice()
    plain = corrected.with_name("room.ply")  # version 0: no user_label field
    out = tmp_path / "m.pt"
    with pytest.raises(ConfigError, match="no corrected points"):
        adapt([Corrected(corrected), Corrected(plain)], out, predictor=predictor, choice=choice)
    bare = tmp_path / "bare.ply"
    write_scan(make_room(1, points=2000), bare)
    with pytest.raises(ConfigError, match="no fused_label field"):
        adapt([Corrected(bare)], out, predictor=predictor, choice=choice)
    with pytest.raises(ConfigError, match="no corrected result"):
        adapt([], out, predictor=predictor, choice=choice)
    assert not out.exists()


def test_the_command_writes_a_model_segment_uses(corrected: Path, tmp_path: Path) -> None:
    out = tmp_path / "site.pt"
    done = run_cli("adapt", str(corrected), "-o", str(out), "--steps", "60", "--replay-rooms", "0")
    assert done.returncode == 0, done.stderr[-2000:]
    assert "corrected points of 1 results" in done.stderr
    card = load_checkpoint(out)[1]
    assert card["adapted"]["corrected_points"] > 500 and card["adapted"]["params"]["steps"] == 60
    assert card["adapted"]["params"]["replay_rooms"] == 0
    seg = run_cli("segment", str(corrected.with_name("room.ply")), "-o", str(tmp_path / "o.ply"),
                  "--weights", str(out), "--report", str(tmp_path / "r.json"))  # fmt: skip
    assert seg.returncode == 0, seg.stderr[-2000:]
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["params"]["network"]["weights"] == str(out)
    wrong = run_cli("adapt", str(corrected), "-o", str(tmp_path / "m.onnx"))
    assert wrong.returncode != 0 and "a .pt file" in wrong.stderr
    assert not (tmp_path / "m.onnx").exists()
    missing = run_cli("adapt", str(corrected), "-o", str(tmp_path / "m.pt"), "--report",
                      str(tmp_path / "nope.json"))  # fmt: skip
    assert missing.returncode != 0 and "no such file" in missing.stderr
    assert not (tmp_path / "m.pt").exists()
