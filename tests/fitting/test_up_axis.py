"""`jointseg fit up-axis` (issue 46, point 2): the up-axis weighing fitted in the package from a
named plan is the same file every time (fresh or from the cache), keeps the geometry steps it
was fitted over, says what it was made from, and is read by the frame stage's loaders; bad plans
are errors that say what is wrong. One small room in two deliveries and a randomly initialised
network as the judge keep it to seconds."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from jointseg.cli import main
from jointseg.exceptions import ConfigError
from jointseg.fitting.provenance import file_sha256, read_provenance
from jointseg.fitting.up_axis import fit_up_axis, fit_weights, read_plan
from jointseg.fitting.up_axis_cases import Case, Gathered
from jointseg.frame import gravity, weigh
from jointseg.frame.model import MODEL_FILE
from jointseg.frame.sources import SIGNED_AXES
from jointseg.io import write_scan
from jointseg.scan import Scan
from jointseg.synth import make_room

DELIVERIES = ["z up, as is", "upside down"]


@pytest.fixture(scope="module")
def plan(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Path:
    folder = tmp_path_factory.mktemp("up_fit")
    write_scan(make_room(21, points=6000), folder / "room21.ply")
    body = {"rooms": ["room21.ply"], "deliveries": DELIVERIES, "views": 0,
            "judge": f"randlanet:{random_weights}"}  # fmt: skip
    path = folder / "plan.json"
    path.write_text(json.dumps(body))
    return path


@pytest.fixture(scope="module")
def fitted(plan: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """The plan fitted twice from scratch (the second filling a cache); and the cache."""
    cache = tmp_path_factory.mktemp("cache")
    outs = []
    for i, where in enumerate((None, cache)):
        out = tmp_path_factory.mktemp(f"out{i}") / "up_model.json"
        fit_up_axis(read_plan(plan), plan.parent, out, command="test", cache=where)
        outs.append(out)
    return outs[0], outs[1], cache


@pytest.mark.slow
def test_the_same_plan_gives_the_same_file(fitted: tuple[Path, Path, Path]) -> None:
    assert fitted[0].read_bytes() == fitted[1].read_bytes()
    assert len(list((fitted[2] / "up").glob("*.json"))) == len(DELIVERIES)


@pytest.mark.slow
def test_the_model_is_read_by_the_frame_stage_and_keeps_the_geometry_steps(
    fitted: tuple[Path, Path, Path],
) -> None:
    model = fitted[0]
    base, full = weigh.fitted_weights(model)
    assert base.shape == (len(weigh.BASE_FEATURES),) and full.shape == (len(weigh.FULL_FEATURES),)
    axis, sign = gravity.model_weights(model)
    shipped_axis, shipped_sign = gravity.model_weights(MODEL_FILE)
    np.testing.assert_array_equal(axis, shipped_axis)
    np.testing.assert_array_equal(sign, shipped_sign)
    body = json.loads(model.read_text())
    assert body["weigh"]["fitted_on"] == ["room21"]
    evidence = weigh.Evidence(np.zeros(6), np.full(3, 1 / 3), np.full(3, 0.5), True, None)
    p = weigh.weigh(evidence, base_weights=base).p
    np.testing.assert_allclose(p, weigh.softmax(evidence.base() @ base))


def test_the_provenance_names_the_room_the_judge_and_the_geometry_steps(
    plan: Path, fitted: tuple[Path, Path, Path], random_weights: Path
) -> None:
    model = fitted[0]
    record = read_provenance(model.with_name("up_model.provenance.json"))
    assert record.model_sha256 == hashlib.sha256(model.read_bytes()).hexdigest()
    [room] = record.scans
    assert (room.name, room.path) == ("room21", "room21.ply")
    assert room.sha256 == file_sha256(plan.parent / "room21.ply")
    [judge] = record.labellers
    assert judge.sha256 == file_sha256(random_weights)
    assert record.facts["geometry_from"]["sha256"] == file_sha256(MODEL_FILE)
    assert record.facts["cases"] == len(DELIVERIES)
    assert record.plan["deliveries"] == DELIVERIES


def test_the_command_from_the_cache_writes_the_same_file(
    plan: Path, fitted: tuple[Path, Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "up.json"
    args = ["fit", "up-axis", "--plan", str(plan), "--out", str(out), "--cache", str(fitted[2])]
    with pytest.raises(SystemExit) as done:
        main(args)
    assert done.value.code == 0
    assert f"2 cases -> {out}" in capsys.readouterr().err
    assert out.read_bytes() == fitted[0].read_bytes()
    record = read_provenance(tmp_path / "up.provenance.json")
    assert record.command == "jointseg " + " ".join(args)


def _row(truth: str, file_axis: str, delivery: str) -> Gathered:
    """A case whose file says ``file_axis`` and whose geometry says nothing."""
    prior = np.zeros(6)
    prior[SIGNED_AXES.index(file_axis)] = 3.0
    evidence = weigh.Evidence(prior, np.full(3, 1 / 3), np.full(3, 0.5), True, None)
    net = {a: np.zeros(len(weigh.FULL_FEATURES) - len(weigh.BASE_FEATURES)) for a in SIGNED_AXES}
    case = Case("r", "s", delivery, truth, Scan(np.zeros((1, 3))))
    return Gathered(case, evidence, net, 0.0)


def test_the_weighing_learns_to_trust_a_file_that_tells_the_truth() -> None:
    rows = [_row("+z", "+z", "z up, as is")] * 5 + [_row("-y", "-y", "as delivered")] * 2
    base, full = fit_weights(rows)
    again = fit_weights(rows)
    np.testing.assert_array_equal(base, again[0])
    np.testing.assert_array_equal(full, again[1])
    assert base[weigh.BASE_FEATURES.index("file")] > 0.5


def test_no_case_of_known_up_is_an_error() -> None:
    row = _row("+z", "+z", "z up, as is")
    row.case.truth = None
    with pytest.raises(ConfigError, match="no cases of known up"):
        fit_weights([row])


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ({"rooms": ["r.ply"], "deliveries": ["sideways"]}, "unknown deliveries"),
        ({"rooms": ["r.ply"], "captures": [{"file": "c.pcd", "truth": "up"}]}, "truth"),
        ({"rooms": []}, "names no rooms and no captures"),
        ({"rooms": ["missing.ply"]}, "no such file or folder"),
        ({"rooms": ["r.ply"], "judge": "nonet"}, "unknown network 'nonet'"),
    ],
)
def test_a_bad_plan_is_an_error_saying_what_is_wrong(
    tmp_path: Path, body: dict, message: str
) -> None:
    write_scan(make_room(22, points=3000), tmp_path / "r.ply")
    path = tmp_path / "plan.json"
    path.write_text(json.dumps(body))
    with pytest.raises(ConfigError, match=message):
        fit_up_axis(read_plan(path), tmp_path, tmp_path / "m.json", command="test")
    assert not (tmp_path / "m.json").exists()
