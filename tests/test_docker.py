"""docker/compose.yaml parses and runs the commands this project has (no image is built here)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
import yaml

from server.lifeline import STOP_GRACE_S
from tests.test_deploy import check_command, setting_names

DOCKER = Path(__file__).resolve().parents[1] / "docker"
COMPOSE = DOCKER / "compose.yaml"


def interpolate(value: Any, env: dict[str, str]) -> Any:
    """Compose's ``${VAR}`` / ``${VAR:-default}`` substitution, through lists and dicts."""
    if isinstance(value, dict):
        return {k: interpolate(v, env) for k, v in value.items()}
    if isinstance(value, list):
        return [interpolate(v, env) for v in value]
    if not isinstance(value, str):
        return value

    def one(match: re.Match[str]) -> str:
        name, default = match[1], match[3]
        return env.get(name) or (default or "")

    return re.sub(r"\$\{(\w+)(:-([^}]*))?\}", one, value)


def services(env: dict[str, str] | None = None) -> dict[str, Any]:
    compose = interpolate(yaml.safe_load(COMPOSE.read_text()), env or {})
    return compose["services"]


def seconds(value: str) -> float:
    """A compose duration such as ``45s`` or ``1m30s``."""
    scale = {"s": 1.0, "m": 60.0, "h": 3600.0}
    return sum(float(n) * scale[u] for n, u in re.findall(r"(\d+(?:\.\d+)?)([smh])", value))


def test_interpolate_follows_compose() -> None:
    assert interpolate("${A:-2}", {}) == "2" and interpolate("${A:-2}", {"A": "5"}) == "5"
    assert interpolate("${A:-2}", {"A": ""}) == "2" and interpolate("x${A}y", {}) == "xy"


def test_compose_file_describes_api_workers_postgres_and_redis() -> None:
    found = services()
    assert set(found) == {"postgres", "redis", "api", "worker"}
    assert found["postgres"]["image"].startswith("postgres:")
    assert found["redis"]["image"].startswith("redis:")
    for role in ("postgres", "redis"):
        assert "healthcheck" in found[role], role


def test_api_runs_serve_without_workers_and_workers_run_worker() -> None:
    found = services()
    api = found["api"]["command"]
    check_command(["/usr/local/bin/jointseg", *api], "serve")  # the image's ENTRYPOINT
    assert api[api.index("--workers") + 1] == "0"
    assert api[api.index("--host") + 1] == "0.0.0.0"
    check_command(["/usr/local/bin/jointseg", *found["worker"]["command"]], "worker")
    assert found["worker"]["command"] == ["worker"]


def test_worker_replicas_follow_jointseg_workers() -> None:
    default = services()["worker"]
    assert int(default["deploy"]["replicas"]) == 2
    four = services({"JOINTSEG_WORKERS": "4"})["worker"]
    assert int(four["deploy"]["replicas"]) == 4
    # inside the containers the same number divides the host's cores into torch threads
    assert four["environment"]["JOINTSEG_WORKERS"] == "4"
    assert "JOINTSEG_WORKERS" not in services()["api"]["environment"]  # --workers 0 anyway


def test_every_service_reaches_the_databases_of_this_file() -> None:
    found = services()
    postgres = found["postgres"]["environment"]
    users = [
        name
        for name, service in found.items()
        if "JOINTSEG_DATABASE_URL" in service.get("environment", {})
    ]
    assert set(users) == {"api", "worker"}
    for name in users:
        service = found[name]
        env = service["environment"]
        unknown = set(env) - setting_names()
        assert not unknown, f"{name} sets {sorted(unknown)}, which are no settings"
        url = urlsplit(env["JOINTSEG_DATABASE_URL"])
        assert url.scheme == "postgresql" and url.hostname == "postgres", name
        assert url.username == postgres["POSTGRES_USER"], name
        assert url.password == postgres["POSTGRES_PASSWORD"], name
        assert url.path.lstrip("/") == postgres["POSTGRES_DB"], name
        assert env["JOINTSEG_QUEUE"] == "redis", name
        assert urlsplit(env["JOINTSEG_REDIS_URL"]).hostname == "redis", name
        for needed in ("postgres", "redis"):
            assert service["depends_on"][needed]["condition"] == "service_healthy", name
        # the shared volume is mounted where the settings put the data directory
        assert f"data:{env['JOINTSEG_DATA_DIR']}" in service["volumes"], name


def test_workers_get_time_to_put_their_job_back() -> None:
    found = services()
    assert seconds(found["worker"]["stop_grace_period"]) > STOP_GRACE_S
    assert seconds(found["api"]["stop_grace_period"]) > STOP_GRACE_S


def compose_tool() -> list[str] | None:
    """``docker compose`` (the plugin) or ``docker-compose``, whichever is installed."""
    docker = shutil.which("docker")
    if docker is not None:
        done = subprocess.run(
            [docker, "compose", "version"], capture_output=True, text=True, timeout=60
        )
        if done.returncode == 0:
            return [docker, "compose"]
    tool = shutil.which("docker-compose")
    return [tool] if tool is not None else None


def test_compose_config_when_a_compose_tool_is_installed() -> None:
    tool = compose_tool()
    if tool is None:
        pytest.skip(
            "neither docker compose nor docker-compose is installed (the YAML is checked above)"
        )
    env = {**os.environ, "JOINTSEG_WORKERS": "3"}
    result = subprocess.run(
        [*tool, "-f", str(COMPOSE), "config"],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
    )
    assert result.returncode == 0, result.stderr
    resolved = yaml.safe_load(result.stdout)["services"]
    assert int(resolved["worker"]["deploy"]["replicas"]) == 3


def test_dockerfile_mirrors_the_setup() -> None:
    text = (DOCKER / "Dockerfile").read_text()
    assert "scripts/setup_system.sh" in text and "torch==2.13.0" in text
    assert "download.pytorch.org/whl/cpu" in text
