"""The shape every benchmark's output shares: before its table, the machine it ran on and the
command that reproduces it, so a number pasted into the docs says where it came from.

Standard library only (torch's version is read from its metadata, its threads only when a
script has loaded it), so printing the header loads nothing a measurement would pay for.
"""

from __future__ import annotations

import os
import platform
import shlex
import sys
import time
from importlib import metadata
from pathlib import Path


def cpu_name() -> str:
    """The CPU's model name (Linux), else what the platform says."""
    info = Path("/proc/cpuinfo")
    if info.is_file():
        for line in info.read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    return platform.processor() or platform.machine()


def cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def torch_line() -> str:
    """torch's version, and its threads when a script has loaded it."""
    try:
        version = metadata.version("torch")
    except metadata.PackageNotFoundError:
        return "no torch"
    torch = sys.modules.get("torch")
    threads = f", {torch.get_num_threads()} threads" if torch is not None else ""
    return f"torch {version}{threads}"


def machine() -> str:
    """One line: CPU, cores, torch, Python, date (UTC)."""
    date = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    python = platform.python_version()
    return f"{cpu_name()}, {cores()} cores, {torch_line()}, Python {python}, {date}"


def command() -> str:
    """The command line that ran this script, as a shell would take it again."""
    return shlex.join([".venv/bin/python", *sys.argv])


def header(title: str = "") -> None:
    """Print the title (when given), the machine and the reproducing command, then a blank
    line: the start of every benchmark's output."""
    if title:
        print(f"# {title}")
    print(f"machine: {machine()}")
    print(f"reproduce: {command()}\n", flush=True)


#: Issue 43's bar: on no judging scan may the vote lose more than this (mIoU points) against
#: its network; bench/structure.py and bench/fit_vote.py count the scans that do.
LOSS_BAR = 0.5


def metric_iou_value(text: str) -> str | float:
    """A ``--metric-iou`` option's value as fusion.metric_iou takes it: "auto" or a number."""
    return text if text == "auto" else float(text)
