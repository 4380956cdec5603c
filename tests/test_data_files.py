"""A data file the library reads that is missing or wrong is an error naming the file, never
zeros or placeholder weights (issue 46): the up-axis model, the vote model, the bundled network
weights. The loaders are pointed at paths in tmp_path; the shipped files are never touched
(tests/test_packaging.py deletes them from an installed copy)."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from jointseg.exceptions import ConfigError
from jointseg.frame import gravity, weigh
from jointseg.frame.model import MODEL_FILE, read_up_model
from jointseg.fusion.tree_runtime import MODEL_PATH, TreeEnsemble
from jointseg.network.backends import WEIGHTS_DIR
from jointseg.network.registry import load


def test_the_shipped_up_model_is_read_and_not_zeros() -> None:
    axis, sign = gravity.model_weights()
    base, full = weigh.fitted_weights()
    assert axis.shape == (gravity.AXIS_SIZE,) and sign.shape == (gravity.SIGN_SIZE,)
    assert base.shape == (len(weigh.BASE_FEATURES),) and full.shape == (len(weigh.FULL_FEATURES),)
    for vector in (axis, sign, base, full):
        assert np.any(vector != 0) and not vector.flags.writeable


def test_a_missing_up_model_is_an_error_naming_it(tmp_path: Path) -> None:
    missing = tmp_path / "up_model.json"
    for read in (read_up_model, gravity.model_weights, weigh.fitted_weights):
        with pytest.raises(ConfigError, match=re.escape(f"{missing} is missing")):
            read(missing)


def test_only_the_shipped_up_model_missing_says_the_installation_is_incomplete(
    tmp_path: Path,
) -> None:
    with pytest.raises(ConfigError) as raised:
        read_up_model(tmp_path / "mine.json")
    assert "installation" not in str(raised.value)
    assert MODEL_FILE.is_file()  # the message for it is checked on an installed copy


def _model_with(tmp_path: Path, **changes: object) -> Path:
    """A copy of the shipped up-axis model with ``changes`` (None removes a key)."""
    body = json.loads(MODEL_FILE.read_text())
    weighing = dict(body["weigh"])
    for key, value in changes.items():
        target = weighing if key in ("features", "base", "full") else body
        if value is None:
            target.pop(key)
        else:
            target[key] = value
    body["weigh"] = weighing
    path = tmp_path / "up_model.json"
    path.write_text(json.dumps(body))
    return path


def test_a_copy_of_the_shipped_up_model_reads_the_same(tmp_path: Path) -> None:
    copy = tmp_path / "up_model.json"
    shutil.copy(MODEL_FILE, copy)
    for mine, shipped in zip(gravity.model_weights(copy), gravity.model_weights(), strict=True):
        np.testing.assert_array_equal(mine, shipped)
    for mine, shipped in zip(weigh.fitted_weights(copy), weigh.fitted_weights(), strict=True):
        np.testing.assert_array_equal(mine, shipped)


@pytest.mark.parametrize(
    ("changes", "read", "message"),
    [
        ({"axis_weights": None}, gravity.model_weights, "'axis_weights' must be 33 finite"),
        ({"sign_weights": [1.0, 2.0]}, gravity.model_weights, "'sign_weights' must be 34"),
        ({"features": ["file"]}, weigh.fitted_weights, r"weighs the features \['file'\]"),
        ({"full": None}, weigh.fitted_weights, "'full' must be 15 finite"),
        ({"base": ["x"] * 7}, weigh.fitted_weights, "'base' must be 7 finite"),
    ],
)
def test_a_wrong_up_model_is_an_error_naming_it_not_placeholders(
    tmp_path: Path, changes: dict[str, object], read: Callable[[Path], object], message: str
) -> None:
    path = _model_with(tmp_path, **changes)
    with pytest.raises(ConfigError, match=message) as raised:
        read(path)
    assert str(path) in str(raised.value)


def test_an_up_model_that_is_no_json_object_is_an_error_naming_it(tmp_path: Path) -> None:
    path = tmp_path / "up_model.json"
    for body in ("{not json", "[1, 2]"):
        path.write_text(body)
        with pytest.raises(ConfigError, match=re.escape(str(path))):
            read_up_model(path)


def test_a_missing_vote_model_is_an_error_naming_it(tmp_path: Path) -> None:
    missing = tmp_path / "vote_model.json"
    with pytest.raises(ConfigError, match=re.escape(f"the vote model {missing} is missing")):
        TreeEnsemble.from_json(missing)
    assert MODEL_PATH.is_file()


def test_missing_bundled_weights_are_an_incomplete_installation(tmp_path: Path) -> None:
    # a file of the package's own weights folder that is not there (none is deleted)
    bundled = WEIGHTS_DIR / "no_such_weights.pt"
    assert not bundled.exists()
    with pytest.raises(ConfigError, match="installation is incomplete") as raised:
        load("randlanet", bundled)
    assert str(bundled) in str(raised.value)
    # weights of the user's own that are missing say where to get weights instead
    with pytest.raises(ConfigError, match="jointseg train") as raised:
        load("randlanet", tmp_path / "mine.pt")
    assert "installation" not in str(raised.value)
