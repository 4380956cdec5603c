"""Provenance records (issue 46, point 2): every model the library ships has one beside it that
matches it byte for byte and names what it was made from; the JSON both are written in depends
only on the content."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from jointseg.exceptions import ConfigError
from jointseg.fitting.outputs import labeller_record
from jointseg.fitting.provenance import (
    git_commit,
    portable_path,
    provenance_path,
    read_provenance,
    stable_json,
)
from jointseg.frame.model import MODEL_FILE as UP_MODEL
from jointseg.fusion.tree_runtime import MODEL_PATH as VOTE_MODEL

ROOT = Path(__file__).resolve().parents[2]
REFIT = {
    VOTE_MODEL: "jointseg fit vote --plan fit/vote.json --out jointseg/fusion/vote_model.json",
    UP_MODEL: "jointseg fit up-axis --plan fit/up_axis.json --out jointseg/frame/up_model.json",
}


@pytest.mark.parametrize("model", [VOTE_MODEL, UP_MODEL], ids=lambda p: p.name)
def test_every_shipped_model_has_a_provenance_that_matches_it(model: Path) -> None:
    record = read_provenance(provenance_path(model))
    assert record.model == model.name
    found = hashlib.sha256(model.read_bytes()).hexdigest()
    assert found == record.model_sha256, (
        f"{model} (sha256 {found[:12]}) is not the model its provenance describes "
        f"({record.model_sha256[:12]}): fit it with `{REFIT[model]}`, which writes both"
    )
    assert record.scans and record.labellers and record.command and record.date
    # a dirty tree's commit does not name the code that fitted it: nobody could refit it
    assert not record.code.commit.endswith("-dirty"), (
        f"{model} was fitted from uncommitted code ({record.code.commit}): fit it from a clean "
        f"checkout with `{REFIT[model]}`"
    )


def test_the_provenance_sits_beside_its_model() -> None:
    assert provenance_path(Path("a/vote_model.json")) == Path("a/vote_model.provenance.json")


def test_stable_json_depends_only_on_the_content() -> None:
    one = stable_json({"b": [0.1, 1e-300, 2.0], "a": {"y": 1, "x": None}})
    two = stable_json({"a": {"x": None, "y": 1}, "b": [0.1, 1e-300, 2.0]})
    assert one == two == '{"a":{"x":null,"y":1},"b":[0.1,1e-300,2.0]}\n'
    assert json.loads(one)["b"][0] == 0.1
    with pytest.raises(ValueError):
        stable_json({"nan": float("nan")})


def test_outside_a_checkout_the_commit_is_unknown(tmp_path: Path) -> None:
    assert git_commit(tmp_path) == "unknown"


def test_a_broken_provenance_is_an_error_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "m.provenance.json"
    with pytest.raises(ConfigError, match="is missing"):
        read_provenance(path)
    path.write_text('{"model": "m.json"}')
    with pytest.raises(ConfigError, match=f"{path} is unreadable"):
        read_provenance(path)


def test_a_record_names_files_from_the_project_root_not_this_machines_folders(
    tmp_path: Path,
) -> None:
    bundled = labeller_record("randlanet")
    assert bundled.weights == "jointseg/network/weights/randlanet_indoor.pt"
    outside = tmp_path / "elsewhere.pt"
    outside.write_bytes(Path(ROOT / bundled.weights).read_bytes())
    record = labeller_record(f"randlanet:{outside}")
    assert record.weights is not None and not Path(record.weights).is_absolute()
    assert (ROOT / record.weights).resolve() == outside.resolve()
    assert record.network == f"randlanet:{record.weights}"
    assert portable_path(ROOT / "fit" / "vote.json") == "fit/vote.json"
