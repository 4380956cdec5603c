"""Extra parts of `jointseg serve` come from an entry-point group (server never imports web):
without any the service still runs and says so, a broken one is skipped with a warning."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from server.serve_parts import SERVE_PARTS_GROUP, load_serve_parts


def test_serve_runs_without_extra_parts_and_says_so(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="server.serve_parts"):
        parts = load_serve_parts("jointseg.no_such_group")
    assert parts.routers == [] and parts.processes == []
    assert "no viewer or job page installed" in caplog.text


def test_a_broken_part_is_skipped_with_a_warning(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    dist = tmp_path / "broken_part-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-part\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(
        f"[{SERVE_PARTS_GROUP}_test]\nbroken = no_such_module_anywhere:parts\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    with caplog.at_level(logging.WARNING, logger="server.serve_parts"):
        parts = load_serve_parts(f"{SERVE_PARTS_GROUP}_test")
    assert parts.routers == [] and parts.processes == []
    assert "skipping 'broken'" in caplog.text
    assert "No module named 'no_such_module_anywhere'" in caplog.text
