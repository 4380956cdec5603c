"""`jointseg submit` against a real service (`jointseg serve` in a subprocess): wait, download,
report, a failing job, an unreachable server, an API key."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from jointseg.cli import main
from jointseg.io import read_scan
from jointseg.pipeline import OUTPUT_FIELDS
from tests.support.cli import run_cli
from tests.support.service_process import free_port, scan_file


def run_here(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """The CLI's ``main`` in this process (no second start of Python and torch)."""
    try:
        main(list(args))
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return scan_file(tmp_path_factory.mktemp("scans"), ".ply", points=3000)


def _config(tmp_path: Path, body: dict) -> str:
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(body))
    return str(path)


def test_submit_wait_download_and_report(service, room, random_weights, tmp_path) -> None:
    out, report = tmp_path / "out.laz", tmp_path / "report.json"
    config = _config(tmp_path, {"network": {"weights": str(random_weights)}})
    args = ["--server", service.url, "--api-key", "key-one", "--config", config]
    result = run_cli("submit", str(room), *args, "-o", str(out), "--report", str(report))
    assert result.returncode == 0, result.stderr
    job_id = result.stdout.strip()
    assert re.fullmatch(r"[0-9a-f]{32}", job_id)
    assert f"job {job_id} succeeded: 3,000 points" in result.stderr
    scan = read_scan(out)
    assert len(scan) == 3000 and set(OUTPUT_FIELDS) <= set(scan.fields)
    assert json.loads(report.read_text())["points"] == 3000


def test_submit_without_wait_prints_the_id_only(service, room, monkeypatch, capsys) -> None:
    monkeypatch.setenv("JOINTSEG_API_KEY", "key-one")
    monkeypatch.setenv("JOINTSEG_SERVER", service.url)
    code, out, err = run_here(capsys, "submit", str(room))
    assert code == 0, err
    assert re.fullmatch(r"[0-9a-f]{32}\n", out)


def test_a_failed_job_is_one_error_line(service, room, random_weights, tmp_path, capsys) -> None:
    # a weights file in the service's weights folder (so the API accepts the job) but no
    # checkpoint: the worker fails the job when it loads the network
    garbage = random_weights.parent / "garbage-cli.pt"
    garbage.write_bytes(b"not a checkpoint")
    config = _config(tmp_path, {"network": {"weights": str(garbage)}})
    args = ["--server", service.url, "--api-key", "key-one", "--config", config, "--wait"]
    code, _, err = run_here(capsys, "submit", str(room), *args)
    assert code == 2
    assert re.search(r"error: job [0-9a-f]{32} failed: .*not a readable PyTorch checkpoint", err)
    assert "Traceback" not in err


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--api-key", "wrong"], "401 invalid API key"),
        ([], "401 missing API key"),
        (["-o", "out.txt"], "results are .ply, .las, .laz files"),
    ],
)
def test_client_errors(service, room, args, message, monkeypatch, capsys) -> None:
    monkeypatch.delenv("JOINTSEG_API_KEY", raising=False)
    code, _, err = run_here(capsys, "submit", str(room), "--server", service.url, *args)
    assert code == 2 and message in err
    assert "Traceback" not in err


def test_unreachable_server(room, capsys) -> None:
    url = f"http://127.0.0.1:{free_port()}"
    code, _, err = run_here(capsys, "submit", str(room), "--server", url)
    assert code == 2 and "cannot reach the job service" in err
