"""Which weights a job may name (server.weights): the function the API checks a config with and
the worker resolves the weights with before it opens them."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from jointseg.exceptions import ConfigError
from server.settings import Settings
from server.weights import resolve_job_weights


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    """A weights folder with one file, a sub-folder, and a link that leads out of it."""
    weights = tmp_path / "weights"
    (weights / "team").mkdir(parents=True)
    (weights / "mine.pt").write_bytes(b"w")
    (weights / "team" / "theirs.pt").write_bytes(b"w")
    outside = tmp_path / "secret.pt"
    outside.write_bytes(b"secret")
    (weights / "escape.pt").symlink_to(outside)
    return weights


def test_names_and_paths_inside_the_folders_resolve(folder: Path) -> None:
    settings = Settings(weights_dirs=[folder])
    assert resolve_job_weights("mine.pt", settings) == (folder / "mine.pt").resolve()
    assert resolve_job_weights("team/theirs.pt", settings).name == "theirs.pt"
    assert resolve_job_weights(str(folder / "mine.pt"), settings).name == "mine.pt"
    bundled = resolve_job_weights("randlanet_indoor.pt", settings)  # the package's own
    assert bundled.is_file()


@pytest.mark.parametrize(
    "value",
    [
        "/etc/hostname",
        "/etc/does-not-exist",
        "../secret.pt",  # next to the folder
        "team/../../secret.pt",
        "escape.pt",  # a link in the folder that leads out of it
        "missing.pt",
        "~/x.pt",
        "mine.pt\x00",
        "a" * 300,
        "",
        "team",  # a folder
    ],
)
def test_everything_else_gets_one_answer(folder: Path, value: str) -> None:
    settings = Settings(weights_dirs=[folder])
    with pytest.raises(ConfigError) as refused:
        resolve_job_weights(value, settings)
    with pytest.raises(ConfigError) as reference:
        resolve_job_weights("/etc/does-not-exist", settings)
    assert str(refused.value) == str(reference.value)
    message = str(refused.value)
    assert message.startswith("config.network.weights: ")
    assert "mine.pt" in message and "escape.pt" not in message  # names, never a path
    assert str(folder) not in message and os.sep + "etc" not in message


def test_without_weights_folders_only_models_and_bundled_files(folder: Path) -> None:
    settings = Settings()
    with pytest.raises(ConfigError):
        resolve_job_weights(str(folder / "mine.pt"), settings)
    with pytest.raises(ConfigError, match="dgcnn-s3dis-6 is not pulled on this service"):
        resolve_job_weights("dgcnn-s3dis-6", settings)
    assert resolve_job_weights("randlanet_indoor_nocolour.pt", settings).is_file()
