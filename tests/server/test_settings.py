"""Settings: environment, JOINTSEG_CONFIG files, derived values, validation, the docs' table."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from server.settings import Settings, settings_table

SETTINGS_PAGE = Path(__file__).resolve().parents[2] / "docs" / "guide" / "job-service.md"


@pytest.fixture(autouse=True)
def clean_env(monkeypatch):
    import os

    for key in list(os.environ):
        if key.startswith("JOINTSEG_"):
            monkeypatch.delenv(key)


def test_defaults_and_sqlite_in_data_dir(tmp_path) -> None:
    settings = Settings(data_dir=tmp_path)
    assert (settings.port, settings.viewer_port, settings.workers) == (8000, 8080, 1)
    assert settings.queue == "sqlite" and settings.api_keys == []
    assert settings.max_upload_bytes == 2 * 1024**3
    assert settings.database_url_resolved == f"sqlite:///{tmp_path / 'jobs.sqlite3'}"


def test_environment_with_prefix_and_key_lists(monkeypatch) -> None:
    monkeypatch.setenv("JOINTSEG_PORT", "9001")
    monkeypatch.setenv("JOINTSEG_API_KEYS", "k-alpha, k-beta,,k-gamma")
    monkeypatch.setenv("JOINTSEG_DATABASE_URL", "postgresql://u@h/db")
    settings = Settings()
    assert settings.port == 9001
    assert settings.api_key_values() == ["k-alpha", "k-beta", "k-gamma"]
    assert "k-alpha" not in repr(settings) and "k-beta" not in str(settings)  # secrets
    assert settings.queue == "postgres"  # implied by the PostgreSQL URL
    monkeypatch.setenv("JOINTSEG_API_KEYS", '["x,y"]')
    assert Settings().api_key_values() == ["x,y"]


def test_config_files_toml_and_env(tmp_path, monkeypatch) -> None:
    toml = tmp_path / "settings.toml"
    toml.write_text('port = 8100\nworkers = 3\nqueue = "redis"\nredis_url = "redis://r:6379/1"\n')
    monkeypatch.setenv("JOINTSEG_CONFIG", str(toml))
    monkeypatch.setenv("JOINTSEG_WORKERS", "4")  # the environment wins over the file
    settings = Settings()
    assert (settings.port, settings.workers, settings.queue) == (8100, 4, "redis")
    dotenv = tmp_path / "service.env"
    dotenv.write_text("JOINTSEG_PORT=8200\n")
    monkeypatch.setenv("JOINTSEG_CONFIG", str(dotenv))
    assert Settings().port == 8200
    monkeypatch.setenv("JOINTSEG_CONFIG", str(tmp_path / "missing.toml"))
    with pytest.raises(ValueError, match="missing.toml: file not found"):
        Settings()


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"queue": "postgres"}, "needs a PostgreSQL database_url"),
        ({"queue": "redis"}, "needs redis_url"),
        ({"heartbeat_interval_s": 5, "heartbeat_timeout_s": 8}, "must exceed twice"),
        ({"queue": "rabbitmq"}, "queue"),
        ({"port": 70000}, "port"),
        ({"max_attempts": 0}, "max_attempts"),
    ],
)
def test_invalid_settings_name_the_problem(values, message) -> None:
    with pytest.raises(ValidationError, match=message):
        Settings(**values)


def test_job_service_page_has_the_settings_table() -> None:
    assert settings_table() in SETTINGS_PAGE.read_text()
