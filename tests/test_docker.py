"""docker/compose.yaml parses and runs the commands this project has (no image is built here)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import yaml

from jointseg.cli.app import app

DOCKER = Path(__file__).resolve().parents[1] / "docker"


def test_compose_file_describes_api_workers_and_postgres() -> None:
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    services = compose["services"]
    assert set(services) == {"postgres", "api", "worker"}
    commands = {c.name for c in app.registered_commands}
    assert services["api"]["command"][0] in commands and services["worker"]["command"] == ["worker"]
    assert services["worker"]["deploy"]["replicas"] >= 1
    for role in ("api", "worker"):
        env = services[role]["environment"]
        assert env["JOINTSEG_DATABASE_URL"].startswith("postgresql://")
        assert services[role]["volumes"] == ["data:/data"]


def test_compose_config_when_a_compose_tool_is_installed() -> None:
    tool = shutil.which("docker-compose")
    if tool is None:
        import pytest

        pytest.skip("docker-compose is not installed (the YAML is checked above)")
    result = subprocess.run(
        [tool, "-f", str(DOCKER / "compose.yaml"), "config", "--quiet"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr


def test_dockerfile_mirrors_the_setup() -> None:
    text = (DOCKER / "Dockerfile").read_text()
    assert "scripts/setup_system.sh" in text and "torch==2.13.0" in text
    assert "download.pytorch.org/whl/cpu" in text
