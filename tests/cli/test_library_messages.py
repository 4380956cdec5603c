"""What `jointseg info` and `jointseg segment` print for a garbage ``.e57`` and for weights that
do not load (issue 44): one ``error:`` line naming the file as the user gave it, without the
debug text, C++ source paths or multi-line advice of libE57Format and torch."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from jointseg.exceptions import ConfigError
from jointseg.network import registry
from tests.support.cli import run_cli

#: What a library's dump carries and a user's message must not.
DEBUG_TEXT = (
    "libE57",
    ".cpp",
    ".cc",
    "Traceback",
    "Debug info",
    "enforce fail",
    "Unsupported operand",
    "weights_only",
    "Error(s) in loading",
    "errors.pydantic.dev",
)


def assert_one_clean_line(text: str, name: str) -> None:
    """One line that starts with the file's name as given, with no library debug text and no
    path other than the one the user gave."""
    assert "\n" not in text.strip(), text
    assert text.startswith(f"{name}: "), text
    rest = text.removeprefix(f"{name}: ")
    for debug in DEBUG_TEXT:
        assert debug not in rest, text
    assert "/" not in rest, text


def test_info_on_a_garbage_e57_prints_one_line(tmp_path: Path) -> None:
    (tmp_path / "scan.e57").write_bytes(b"ASTM-E57" + np.random.default_rng(0).bytes(3000))
    result = run_cli("info", "scan.e57", cwd=tmp_path)
    assert result.returncode == 2
    assert result.stderr.startswith("error: "), result.stderr
    assert_one_clean_line(result.stderr.removeprefix("error: ").strip(), "scan.e57")
    assert "not a readable E57 file" in result.stderr


def _write_bad_weights(path: Path, case: str) -> None:
    body: object
    if case == "noise":
        path.write_bytes(np.random.default_rng(3).bytes(4000))
        return
    if case == "empty":
        path.write_bytes(b"")
        return
    if case == "zip":
        with zipfile.ZipFile(path, "w") as archive:
            archive.writestr("x.txt", "not a tensor archive")
        return
    if case == "bad-config":
        body = {"format": "jointseg-randlanet/1", "config": {"bogus": 1}, "state_dict": {}}
    elif case == "no-config":
        body = {"format": "jointseg-randlanet/1"}
    elif case == "state-list":
        body = {"format": "jointseg-randlanet/1", "config": {}, "state_dict": [1, 2]}
    else:  # wrong tensors
        body = {"format": "jointseg-randlanet/1", "config": {}, "state_dict": {"a": torch.ones(2)}}
    torch.save(body, path)


@pytest.mark.parametrize(
    "case", ["noise", "empty", "zip", "bad-config", "no-config", "state-list", "wrong-tensors"]
)
@pytest.mark.parametrize("suffix", [".pt", ".t7"])
def test_weights_that_do_not_load_are_a_one_line_config_error(
    tmp_path: Path, case: str, suffix: str
) -> None:
    """RandLA-Net (.pt) and DGCNN (.t7) weights, loaded as `segment --weights` loads them."""
    path = tmp_path / f"w{suffix}"
    _write_bad_weights(path, case)
    with pytest.raises(ConfigError) as refused:
        registry.load(str(path), device="cpu")
    assert_one_clean_line(str(refused.value), str(path))
    if case == "empty":  # says what is wrong, not an empty "()"
        assert "the file is empty" in str(refused.value)


@pytest.mark.slow
def test_segment_with_garbage_weights_prints_one_line(tmp_path: Path) -> None:
    np.savetxt(tmp_path / "room.xyz", np.random.default_rng(4).random((2000, 3)) * 3)
    _write_bad_weights(tmp_path / "mine.pt", "noise")
    result = run_cli(
        "segment",
        "room.xyz",
        "-o",
        "out.ply",
        "--weights",
        "mine.pt",
        "--device",
        "cpu",
        cwd=tmp_path,
    )
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert len(lines) == 1, result.stderr
    assert_one_clean_line(lines[0].removeprefix("error: "), "mine.pt")
    assert "not a readable PyTorch checkpoint" in lines[0]
