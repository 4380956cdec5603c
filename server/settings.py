"""Every setting of the job service in one pydantic-settings class.

Values come from (highest priority first) keyword arguments, ``JOINTSEG_*`` environment
variables, the file named by ``JOINTSEG_CONFIG`` (``.toml``, or ``.env`` style for any other
name) and the defaults below. :func:`settings_table` renders the settings table of
docs/guide/job-service.md from the fields, so the documentation cannot drift from the code.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import (
    BaseSettings,
    DotEnvSettingsSource,
    NoDecode,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

ENV_PREFIX = "JOINTSEG_"
#: Environment variable naming an optional settings file (.toml, or KEY=value lines).
CONFIG_ENV = "JOINTSEG_CONFIG"

QueueKind = Literal["sqlite", "postgres", "redis"]
GIB = 1 << 30
MIB = 1 << 20

#: The service's default point limit: what one worker is measured to handle on the 24 GB /
#: 2-core reference machine. `bench/big.py`: a 50 M-point floor through `jointseg segment`, cut
#: into 4 M-point tiles, peaks at 4.65 GB (449 s); untiled, 20 M points already took 8.7 GB.
SERVICE_MAX_POINTS = 50_000_000
#: The largest tile a job may ask for: a 20 M-point floor in 4 M-point tiles peaks at 3.0 GB.
TILE_POINTS_LIMIT = 4_000_000


class Settings(BaseSettings):
    """Settings of the API, the workers and (through ``viewer_*``) the viewer."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, extra="ignore", frozen=True)

    data_dir: Path = Field(
        Path("data"),
        description="Uploads, results, the SQLite job table and queue. Shared by every API and "
        "worker (NFS or equivalent when they run on several machines).",
    )
    host: str = Field("127.0.0.1", description="Address the API listens on.")
    port: int = Field(8000, ge=0, le=65535, description="Port of the API.")
    viewer_host: str = Field("127.0.0.1", description="Address the viewer listens on.")
    viewer_port: int = Field(8080, ge=0, le=65535, description="Port of the viewer.")
    database_url: str | None = Field(
        None,
        description="SQLAlchemy URL of the job table, e.g. `postgresql://user:pw@host/db`; "
        "default: SQLite file `jobs.sqlite3` in data_dir.",
    )
    queue: QueueKind = Field(
        "sqlite",
        description="Huey storage of the queue: `sqlite` (file in data_dir), `postgres` (the "
        "database_url database; implied by a PostgreSQL database_url) or `redis` (redis_url).",
    )
    redis_url: str | None = Field(
        None, description="Redis URL for `queue=redis`, e.g. `redis://host:6379/0`."
    )
    queue_name: str = Field(
        "jointseg",
        min_length=1,
        description="Name of the Huey queue (Redis key prefix; row tag in SQL storage).",
    )
    api_keys: Annotated[list[SecretStr], NoDecode] = Field(
        default_factory=list,
        description="Accepted API keys (comma-separated or a JSON list); empty: no key needed. "
        "Clients send `Authorization: Bearer <key>`. Each key sees and manages only the jobs "
        "it submitted.",
    )
    admin_keys: Annotated[list[SecretStr], NoDecode] = Field(
        default_factory=list,
        description="API keys that see and manage every job, whoever submitted it (accepted "
        "besides api_keys; comma-separated or a JSON list).",
    )
    max_upload_bytes: int = Field(2 * GIB, gt=0, description="Largest upload accepted (413).")
    max_points: int = Field(
        SERVICE_MAX_POINTS,
        gt=0,
        description="Largest scan accepted (422); the default is what one worker is measured to "
        "handle in tiles (4.65 GB at 50 M points; bench/big.py).",
    )
    max_tile_points: int = Field(
        TILE_POINTS_LIMIT,
        gt=0,
        description="Largest tiles.max_points a job config may ask for (422): a scan is held "
        "in a worker's memory one tile at a time, so this, not max_points, sizes a worker "
        "(about 3 GB at 4 M points a tile; bench/big.py).",
    )
    max_span: float = Field(
        500_000.0,
        gt=0,
        le=1e9,
        description="Largest extent of a scan's coordinates along any axis, in its own units "
        "(422 at upload, or the job fails naming the span): 500 m even in millimetres; "
        "spans far beyond a building only exhaust a worker's memory.",
    )
    max_inflation: float = Field(
        200.0,
        ge=1,
        description="Largest ratio of the bytes a compressed upload (LAZ, NPZ, PCD, E57) "
        "declares to the bytes it stores (422): real LAZ scans are 3-15, a header lying "
        "about its point count or a zip bomb (1000 for zeros) far more.",
    )
    full_check_max_bytes: int = Field(
        64 * MIB,
        ge=0,
        description="Uploads up to this size are read completely before queuing (every point "
        "checked, e.g. for NaN, in a checking process, never in the API's); larger ones only "
        "by header and size, their body when the job runs.",
    )
    workers: int = Field(1, ge=0, description="Worker processes `jointseg serve` starts.")
    torch_threads: int | None = Field(
        None,
        ge=1,
        description="torch threads per worker; default: this machine's CPU cores shared among "
        "the workers live on it, counted at each job or tile (at least 1).",
    )
    worker_nice: int = Field(
        10,
        ge=0,
        le=19,
        description="Niceness added to worker processes, so the API stays responsive on a "
        "machine whose cores the workers keep busy.",
    )
    heartbeat_interval_s: float = Field(
        2.0,
        gt=0,
        description="How often a worker's heartbeat process stamps its job (or tile) and "
        "itself as alive, and how often each worker runs the reaper.",
    )
    heartbeat_timeout_s: float = Field(
        10.0,
        gt=0,
        description="A running job or tile without a heartbeat for this long is re-queued (or "
        "failed), and its worker is no longer listed as live: the lease.",
    )
    max_attempts: int = Field(
        3, ge=1, description="Starts of one job before a lost worker fails it for good."
    )
    queue_poll_s: float = Field(
        0.5, gt=0, description="Longest wait of an idle worker between queue polls."
    )
    weights_dirs: list[Path] = Field(
        default_factory=list,
        description="Folders (a JSON list) whose files a job's `network.weights` may name, by "
        "name or path; besides them only pulled published models and the bundled weights. "
        "Anything else gets one 422, whether or not such a file exists.",
    )
    log_level: str = Field("INFO", description="Logging level of the API and the workers.")

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        """Keyword arguments, then the environment, then the ``JOINTSEG_CONFIG`` file."""
        sources: list[PydanticBaseSettingsSource] = [init_settings, env_settings]
        config_file = os.environ.get(CONFIG_ENV)
        if config_file:
            path = Path(config_file)
            if not path.is_file():
                raise ValueError(f"{CONFIG_ENV}={config_file}: file not found")
            if path.suffix.lower() == ".toml":
                sources.append(TomlConfigSettingsSource(settings_cls, toml_file=path))
            else:
                sources.append(DotEnvSettingsSource(settings_cls, env_file=path))
        return tuple(sources)

    @model_validator(mode="before")
    @classmethod
    def _postgres_implies_queue(cls, data: Any) -> Any:
        if isinstance(data, dict) and not data.get("queue"):
            url = str(data.get("database_url") or "")
            if url.startswith(("postgresql", "postgres:")):
                data = {**data, "queue": "postgres"}
        return data

    @field_validator("api_keys", "admin_keys", mode="before")
    @classmethod
    def _split_keys(cls, value: Any) -> Any:
        if isinstance(value, str):
            text = value.strip()
            if text.startswith("["):
                return json.loads(text)
            return [k.strip() for k in text.split(",") if k.strip()]
        return value

    @model_validator(mode="after")
    def _consistent(self) -> Settings:
        if self.queue == "postgres" and not self.database_url_resolved.startswith("postgres"):
            raise ValueError("queue=postgres needs a PostgreSQL database_url")
        if self.queue == "redis" and not self.redis_url:
            raise ValueError("queue=redis needs redis_url")
        if self.heartbeat_timeout_s <= 2 * self.heartbeat_interval_s:
            raise ValueError(
                f"heartbeat_timeout_s ({self.heartbeat_timeout_s}) must exceed twice "
                f"heartbeat_interval_s ({self.heartbeat_interval_s})"
            )
        return self

    @property
    def database_url_resolved(self) -> str:
        """database_url, or the SQLite file in data_dir."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'jobs.sqlite3').resolve()}"

    @property
    def keys_required(self) -> bool:
        """Whether requests need a key: any key configured, admin or not (else the service is
        open and every caller sees every job)."""
        return bool(self.api_keys or self.admin_keys)

    def api_key_values(self) -> list[str]:
        """The configured keys in clear (for comparison only; never log them)."""
        return [k.get_secret_value() for k in self.api_keys]

    def admin_key_values(self) -> list[str]:
        """The admin keys in clear (for comparison only; never log them)."""
        return [k.get_secret_value() for k in self.admin_keys]


def settings_table() -> str:
    """The settings as a Markdown table: environment variable, default, meaning."""
    rows = ["| environment variable | default | meaning |", "|---|---|---|"]
    for name, field in Settings.model_fields.items():
        if field.default_factory is not None:
            default = "empty"
        elif field.default is None:
            default = "—"
        else:
            default = f"`{field.default}`"
        rows.append(f"| `{ENV_PREFIX}{name.upper()}` | {default} | {field.description} |")
    return "\n".join(rows)
