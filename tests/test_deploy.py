"""deploy/systemd: the units run commands and options this project has, with the settings it
reads, and systemd itself accepts them (``systemd-analyze verify``, where it is installed)."""

from __future__ import annotations

import configparser
import functools
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from jointseg.network.published import CACHE_ENV
from server.lifeline import STOP_GRACE_S
from server.settings import CONFIG_ENV, ENV_PREFIX, Settings

ROOT = Path(__file__).resolve().parents[1]
SYSTEMD = ROOT / "deploy" / "systemd"
API_UNIT = SYSTEMD / "jointseg-api.service"
WORKER_UNIT = SYSTEMD / "jointseg-worker@.service"
ENV_FILE = SYSTEMD / "jointseg.env"
OPERATIONS = ROOT / "docs" / "guide" / "operations.md"
#: Where the units and the operations page tell the operator to put the settings.
ENV_PATH = "/etc/jointseg/jointseg.env"
#: Variables a unit or the settings file may set besides the Settings fields.
OTHER_VARIABLES = {CONFIG_ENV, CACHE_ENV}
#: The jointseg executable of this environment (the venv's, next to the interpreter).
JOINTSEG = Path(sys.executable).with_name("jointseg")


class _Repeated(dict):  # type: ignore[type-arg]
    """configparser's section dict keeping every value of a key systemd allows to repeat
    (Environment=, After=): configparser reads values into lists, this extends the list."""

    def __setitem__(self, key: str, value: Any) -> None:
        if isinstance(value, list) and key in self:
            self[key].extend(value)
        else:
            super().__setitem__(key, value)


def read_unit(path: Path) -> configparser.ConfigParser:
    """A unit file as configparser reads it: case kept, no interpolation (% is systemd's),
    repeated keys joined by newlines."""
    parser = configparser.ConfigParser(
        strict=False, interpolation=None, delimiters=("=",), dict_type=_Repeated
    )
    parser.optionxform = str  # type: ignore[assignment,method-assign]
    parser.read_string(path.read_text(), source=str(path))
    return parser


def unit_environment(unit: configparser.ConfigParser) -> dict[str, str]:
    """The variables of every Environment= line."""
    found: dict[str, str] = {}
    for line in unit["Service"].get("Environment", "").splitlines():
        for item in shlex.split(line):
            name, _, value = item.partition("=")
            found[name] = value
    return found


def seconds(value: str) -> float:
    """A systemd time span such as ``45s``, ``2min`` or ``1min 30s``, in seconds."""
    scale = {"": 1.0, "s": 1.0, "sec": 1.0, "ms": 1e-3, "m": 60.0, "min": 60.0}
    parts = re.findall(r"(\d+(?:\.\d+)?)\s*([a-z]*)", value)
    assert parts, f"not a time span: {value!r}"
    return sum(float(number) * scale[unit] for number, unit in parts)


def read_env_file(path: Path) -> tuple[dict[str, str], set[str]]:
    """(the KEY=value lines, the names of the commented-out ``# KEY=value`` lines)."""
    active: dict[str, str] = {}
    commented: set[str] = set()
    for line in path.read_text().splitlines():
        if match := re.fullmatch(r"([A-Z][A-Z0-9_]*)=(.*)", line):
            active[match[1]] = match[2]
        elif match := re.fullmatch(r"#\s*([A-Z][A-Z0-9_]*)=.*", line):
            commented.add(match[1])
    return active, commented


def setting_names() -> set[str]:
    """JOINTSEG_HOST, JOINTSEG_DATA_DIR, ...: the variable of every Settings field."""
    return {f"{ENV_PREFIX}{name.upper()}" for name in Settings.model_fields}


@functools.cache
def cli_options(command: str) -> frozenset[str]:
    """The options ``jointseg <command> --help`` lists, from the installed executable."""
    assert JOINTSEG.is_file(), f"no jointseg executable next to {sys.executable}"
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1", "TERM": "dumb"}
    done = subprocess.run(
        [str(JOINTSEG), command, "--help"], capture_output=True, text=True, env=env, timeout=120
    )
    assert done.returncode == 0, done.stderr
    return frozenset(re.findall(r"(?<![\w-])--[a-z][a-z-]*", done.stdout))


def check_command(argv: list[str], command: str) -> None:
    """argv runs ``jointseg <command>`` with options of that command only."""
    assert Path(argv[0]).name == "jointseg" and Path(argv[0]).is_absolute(), argv
    assert argv[1] == command, argv
    options = {a.partition("=")[0] for a in argv[2:] if a.startswith("--")}
    unknown = options - cli_options(command)
    assert not unknown, f"`jointseg {command}` has no {sorted(unknown)}"


def exec_start(unit: configparser.ConfigParser) -> list[str]:
    lines = unit["Service"]["ExecStart"].splitlines()
    assert len(lines) == 1, lines
    return shlex.split(lines[0])


def test_cli_options_reads_the_real_help() -> None:
    # the helper the checks below rely on: it finds serve's options and not made-up ones
    assert {"--workers", "--host", "--data-dir", "--no-viewer"} <= cli_options("serve")
    assert "--workers" not in cli_options("worker")
    with pytest.raises(AssertionError, match="has no"):
        check_command([str(JOINTSEG), "worker", "--workers", "2"], "worker")


def test_api_unit_runs_serve_without_workers_under_its_own_user() -> None:
    unit = read_unit(API_UNIT)
    service = unit["Service"]
    argv = exec_start(unit)
    check_command(argv, "serve")
    assert argv[argv.index("--workers") + 1] == "0"
    assert service["EnvironmentFile"] == ENV_PATH
    assert service["User"] == "jointseg" and service["Group"] == "jointseg"
    assert service["Restart"] == "on-failure"
    assert service["NoNewPrivileges"] == "yes" and service["PrivateTmp"] == "yes"
    assert service["ProtectSystem"] == "strict"
    assert unit["Install"]["WantedBy"] == "multi-user.target"


def test_worker_template_runs_one_worker_per_instance() -> None:
    unit = read_unit(WORKER_UNIT)
    service = unit["Service"]
    check_command(exec_start(unit), "worker")
    assert WORKER_UNIT.name.endswith("@.service")
    assert "%i" in unit["Unit"]["Description"] and "%i" in service["SyslogIdentifier"]
    assert service["EnvironmentFile"] == ENV_PATH
    assert service["User"] == "jointseg"
    assert service["Restart"] == "always"
    assert service["NoNewPrivileges"] == "yes" and service["PrivateTmp"] == "yes"
    assert unit["Install"]["WantedBy"] == "multi-user.target"


def test_worker_gets_time_to_put_its_job_back() -> None:
    # SIGTERM to the worker alone (KillMode=mixed, as `jointseg serve` stops its workers), then
    # more time than the worker may take to re-queue its job before systemd's SIGKILL
    service = read_unit(WORKER_UNIT)["Service"]
    assert service["KillSignal"] == "SIGTERM" and service["KillMode"] == "mixed"
    assert seconds(service["TimeoutStopSec"]) > STOP_GRACE_S
    api = read_unit(API_UNIT)["Service"]
    assert seconds(api["TimeoutStopSec"]) > STOP_GRACE_S


def test_worker_niceness_is_set_once() -> None:
    # the worker adds JOINTSEG_WORKER_NICE to the niceness it starts with: with the unit's Nice=10
    # it must be 0, or workers run at 19
    unit = read_unit(WORKER_UNIT)
    assert int(unit["Service"]["Nice"]) == 10
    assert unit_environment(unit)[f"{ENV_PREFIX}WORKER_NICE"] == "0"
    active, _ = read_env_file(ENV_FILE)
    assert f"{ENV_PREFIX}WORKER_NICE" not in active  # it would override Environment=


def test_units_may_write_the_data_dir_of_the_settings_file() -> None:
    # ProtectSystem=strict leaves only ReadWritePaths= writable; the shared directory is mounted
    # first (RequiresMountsFor=)
    data_dir = read_env_file(ENV_FILE)[0][f"{ENV_PREFIX}DATA_DIR"]
    for path in (API_UNIT, WORKER_UNIT):
        unit = read_unit(path)
        assert data_dir in unit["Service"]["ReadWritePaths"].split(), path.name
        assert data_dir in unit["Unit"]["RequiresMountsFor"].split(), path.name
        # the model cache, read-only in ~ under ProtectHome=, moves to CacheDirectory=
        assert unit["Service"]["ProtectHome"] == "yes"
        cache = unit["Service"]["CacheDirectory"]
        assert unit_environment(unit)[CACHE_ENV] == f"/var/cache/{cache}", path.name


def test_unit_environment_names_real_variables() -> None:
    for path in (API_UNIT, WORKER_UNIT):
        unknown = set(unit_environment(read_unit(path))) - setting_names() - OTHER_VARIABLES
        assert not unknown, f"{path.name} sets {sorted(unknown)}, which nothing reads"


def test_settings_file_holds_real_settings_that_load(monkeypatch: pytest.MonkeyPatch) -> None:
    active, commented = read_env_file(ENV_FILE)
    unknown = (set(active) | commented) - setting_names() - OTHER_VARIABLES
    assert not unknown, f"jointseg.env names {sorted(unknown)}, which are no settings"
    for name in list(os.environ):
        if name.startswith(ENV_PREFIX):
            monkeypatch.delenv(name)
    for name, value in active.items():
        monkeypatch.setenv(name, value)
    settings = Settings()
    assert settings.database_url is not None and settings.database_url.startswith("postgresql://")
    assert settings.queue == "redis" and settings.redis_url is not None
    assert settings.data_dir == Path("/var/lib/jointseg")
    assert settings.torch_threads is not None


def test_operations_page_names_real_settings_and_the_shipped_files() -> None:
    text = OPERATIONS.read_text()
    named = set(re.findall(r"\bJOINTSEG_[A-Z0-9_]*[A-Z0-9]\b", text))
    unknown = named - setting_names() - OTHER_VARIABLES
    assert not unknown, f"operations.md names {sorted(unknown)}, which are no settings"
    for path in (API_UNIT, WORKER_UNIT, ENV_FILE, ROOT / "docker" / "compose.yaml"):
        assert str(path.relative_to(ROOT)) in text, path.name
    for flag in re.findall(r"jointseg serve ([^`\n]*)", text):
        options = {a for a in flag.split() if a.startswith("--")}
        assert options <= cli_options("serve"), flag


def _heartbeat_defaults() -> tuple[float, float]:
    fields = Settings.model_fields
    interval = fields["heartbeat_interval_s"].default
    timeout = fields["heartbeat_timeout_s"].default
    assert isinstance(interval, float) and isinstance(timeout, float)
    return interval, timeout


def test_settings_file_gives_the_shipped_heartbeat() -> None:
    interval, timeout = _heartbeat_defaults()
    text = ENV_FILE.read_text()
    assert f"# {ENV_PREFIX}HEARTBEAT_INTERVAL_S={interval:g}\n" in text
    assert f"# {ENV_PREFIX}HEARTBEAT_TIMEOUT_S={timeout:g}\n" in text


def test_operations_page_gives_the_shipped_heartbeat() -> None:
    interval, timeout = _heartbeat_defaults()
    text = " ".join(OPERATIONS.read_text().split())  # line breaks as spaces
    assert f"heartbeat every {interval:g} s" in text
    assert f"heartbeat timeout of {timeout:g} s" in text
    # the page's bound on a dead worker's work running again: up to one interval between its
    # last heartbeat and its death, the timeout, up to one interval until the next sweep
    promised = re.search(r"runs on another worker, within about (\d+) s", text)
    assert promised is not None
    assert timeout + 2 * interval <= float(promised[1])


SYSTEMD_ANALYZE = shutil.which("systemd-analyze")
needs_systemd_analyze = pytest.mark.skipif(
    SYSTEMD_ANALYZE is None, reason="systemd-analyze is not installed (the units are parsed above)"
)


def verify(folder: Path, unit: str) -> subprocess.CompletedProcess[str]:
    """``systemd-analyze verify`` of ``folder/unit``; its complaints go to stderr."""
    assert SYSTEMD_ANALYZE is not None
    return subprocess.run(
        [SYSTEMD_ANALYZE, "verify", "--man=no", str(folder / unit)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "SYSTEMD_LOG_COLOR": "0", "SYSTEMD_PAGER": ""},
    )


def installed_copy(tmp_path: Path) -> Path:
    """The units in a folder of their own, ExecStart pointing at this environment's jointseg
    (verify fails on an ExecStart that is not executable; /opt/jointseg is not installed here).
    """
    folder = tmp_path / "units"
    folder.mkdir()
    for path in (API_UNIT, WORKER_UNIT):
        text = path.read_text()
        argv = exec_start(read_unit(path))
        assert text.count(argv[0]) == 1, path.name
        (folder / path.name).write_text(text.replace(argv[0], str(JOINTSEG)))
    return folder


@needs_systemd_analyze
@pytest.mark.parametrize("unit", ["jointseg-api.service", "jointseg-worker@2.service"])
def test_systemd_analyze_verify_accepts_the_units(tmp_path: Path, unit: str) -> None:
    done = verify(installed_copy(tmp_path), unit)
    assert done.returncode == 0 and not (done.stdout + done.stderr).strip(), (
        f"systemd-analyze verify {unit}:\n{done.stdout}{done.stderr}"
    )


@needs_systemd_analyze
def test_systemd_analyze_verify_notices_a_bad_unit(tmp_path: Path) -> None:
    # verify exits 0 on a key it ignores and only says so: the empty output checked above is
    # what tells a good unit from this one
    folder = installed_copy(tmp_path)
    text = (folder / API_UNIT.name).read_text()
    broken = text.replace("Restart=on-failure", "Restart=sometimes\nRestartSecs=2")
    assert broken != text
    (folder / API_UNIT.name).write_text(broken)
    done = verify(folder, API_UNIT.name)
    complaints = done.stdout + done.stderr
    assert "sometimes" in complaints and "RestartSecs" in complaints, complaints
