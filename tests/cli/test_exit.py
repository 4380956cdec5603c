"""The console script leaves without the interpreter's module-by-module teardown
(jointseg.cli.app.leave), and still runs exit handlers, flushes its output, keeps its exit
status and waits for a thread that is still working."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


def _leave(tmp_path: Path, body: str) -> subprocess.CompletedProcess[str]:
    script = tmp_path / "leave.py"
    script.write_text(
        "import atexit, sys, threading, time\n"
        "from pathlib import Path\n"
        "from jointseg.cli.app import leave\n"
        f"out = Path({str(tmp_path)!r})\n"
        "atexit.register(lambda: (out / 'atexit').write_text('ran'))\n"
        "sys.stdout.write('buffered, no newline')\n" + body
    )
    return subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize("code", [0, 3])
def test_leave_runs_exit_handlers_flushes_and_keeps_the_status(tmp_path: Path, code: int) -> None:
    done = _leave(tmp_path, f"leave({code})\nprint('never')\n")
    assert done.returncode == code
    assert done.stdout == "buffered, no newline"
    assert (tmp_path / "atexit").read_text() == "ran"


def test_leave_waits_for_a_working_thread(tmp_path: Path) -> None:
    done = _leave(
        tmp_path,
        "def work():\n"
        "    time.sleep(0.5)\n"
        "    (out / 'thread').write_text('finished')\n"
        "threading.Thread(target=work).start()\n"
        "leave(0)\n",
    )
    assert done.returncode == 0
    assert (tmp_path / "thread").read_text() == "finished"


def test_leave_prints_a_message_status_as_sys_exit_does(tmp_path: Path) -> None:
    done = _leave(tmp_path, "leave('went wrong')\n")
    assert done.returncode == 1
    assert "went wrong" in done.stderr


def test_the_console_script_exits_with_the_commands_status(tmp_path: Path) -> None:
    missing = tmp_path / "none.ply"
    done = subprocess.run(
        [sys.executable, "-m", "jointseg", "info", str(missing)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2
    assert "file not found" in done.stderr
