"""The commit-msg hook (scripts/check_commit_msg.py): subjects of at most 72 characters, the
details in a body after a blank line."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "check_commit_msg.py"


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location("check_commit_msg", SCRIPT)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


check = _load()


@pytest.mark.parametrize(
    "message",
    [
        "x" * 72,
        "Short subject\n\nThe details, in a body\nover two lines.\n",
        "# a comment git adds\nShort subject\n\n# another\n",
        "Short subject\n\n" + check.SCISSORS + "\ndiff --git a/x b/x\n" + "y" * 100 + "\n",
        "Merge branch '" + "b" * 80 + "'\n",
    ],
)
def test_good_messages_pass(message: str) -> None:
    assert check.problems(message) == []


@pytest.mark.parametrize(
    ("message", "words"),
    [
        ("x" * 73, "73 characters"),
        ("Short subject\nthe body glued on\n", "blank line"),
        ("# only a comment\n\n", "empty"),
        ("\n\n" + "x" * 80 + "\n\nbody\n", "80 characters"),
    ],
)
def test_bad_messages_are_named(message: str, words: str) -> None:
    found = check.problems(message)
    assert len(found) == 1 and words in found[0]


def test_the_hook_exits_non_zero_on_a_long_subject_as_git_runs_it(tmp_path: Path) -> None:
    good, bad = tmp_path / "good", tmp_path / "bad"
    good.write_text("Short subject\n\nbody\n")
    bad.write_text("s" * 90 + "\n")
    run = [sys.executable, str(SCRIPT)]
    assert subprocess.run([*run, str(good)], capture_output=True).returncode == 0
    rejected = subprocess.run([*run, str(bad)], capture_output=True, text=True)
    assert rejected.returncode == 1 and "90 characters" in rejected.stderr


def test_pre_commit_runs_the_hook_at_the_commit_msg_stage() -> None:
    config = (SCRIPT.parents[1] / ".pre-commit-config.yaml").read_text()
    hook = config[config.index("id: commit-msg-length") :]
    assert "scripts/check_commit_msg.py" in hook and "stages: [commit-msg]" in hook
