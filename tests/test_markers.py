"""The suite's markers (pyproject.toml) and how tests/conftest.py hands them out: chromium tests
are ``browser``, tests with a real service or database ``service``, and `make test-fast`'s
selection leaves both out, with the ``slow`` ones, and keeps the plain unit tests."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Collects (never runs) the given tests in a fresh pytest and writes, for each, its markers and
#: whether the ``-m`` selection kept it.
COLLECT = """
import json, sys
import pytest

class Record:
    @pytest.hookimpl(wrapper=True)
    def pytest_collection_modifyitems(self, items):
        every = list(items)
        result = yield
        kept = {id(item) for item in items}
        self.found = {
            item.nodeid: {"marks": sorted({m.name for m in item.iter_markers()}),
                          "kept": id(item) in kept}
            for item in every
        }
        return result

record = Record()
pytest.main(["--collect-only", "-q", "-p", "no:cacheprovider", *sys.argv[2:]], plugins=[record])
with open(sys.argv[1], "w") as out:
    json.dump(record.found, out)
"""
FILES = [
    "tests/web/test_viewer_browser.py",  # chromium, on a viewer
    "tests/web/test_page.py",  # the job page through a TestClient, and one test in chromium
    "tests/server/test_jobs_api.py",  # the shared `jointseg serve`
    "tests/server/test_tile_states.py",  # parametrised: SQLite, and PostgreSQL
    "tests/server/test_process_lifecycle.py",  # marked by hand, beside a unit test
    "tests/test_packaging.py",  # builds a wheel: slow
    "tests/io/test_ply.py",
]


def _fast_selection() -> str:
    """The ``-m`` expression of the Makefile's test-fast target."""
    found = re.search(
        r'^test-fast:.*\n\t.*pytest.* -m "([^"]+)"', (ROOT / "Makefile").read_text(), re.M
    )
    assert found, "the Makefile has no test-fast target running pytest -m"
    return found.group(1)


@pytest.fixture(scope="module")
def collected(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("markers") / "collected.json"
    command = [sys.executable, "-c", COLLECT, str(out), "-m", _fast_selection(), *FILES]
    subprocess.run(command, cwd=ROOT, check=True, capture_output=True, timeout=300)
    return json.loads(out.read_text())


def _find(collected: dict[str, Any], path: str, name: str = "") -> list[dict[str, Any]]:
    found = [v for k, v in collected.items() if k.startswith(path) and name in k]
    assert found, f"no test of {path} matching {name!r} was collected"
    return found


def test_chromium_tests_are_browser_and_left_out_of_test_fast(collected) -> None:
    for test in _find(collected, "tests/web/test_viewer_browser.py"):
        assert "browser" in test["marks"] and not test["kept"]
    # by its fixture alone, in a module of unit tests
    (tiles,) = _find(collected, "tests/web/test_page.py", "tiles_done_of_total")
    assert "browser" in tiles["marks"] and not tiles["kept"]


def test_tests_with_a_service_or_postgres_are_service(collected) -> None:
    for test in _find(collected, "tests/server/test_jobs_api.py"):
        assert "service" in test["marks"] and "browser" not in test["marks"]
        assert not test["kept"]
    for test in _find(collected, "tests/server/test_tile_states.py", "[postgres]"):
        assert "service" in test["marks"] and not test["kept"]
    (killed,) = _find(collected, "tests/server/test_process_lifecycle.py", "test_sigkill_of_serve")
    assert "service" in killed["marks"] and not killed["kept"]


def test_slow_tests_are_left_out_of_test_fast(collected) -> None:
    for test in _find(collected, "tests/test_packaging.py", "installed_wheel"):
        assert "slow" in test["marks"] and not test["kept"]


def test_unit_tests_stay_in_test_fast_unmarked(collected) -> None:
    unit = [
        *_find(collected, "tests/io/test_ply.py"),
        *_find(collected, "tests/web/test_page.py", "plain_html"),
        *_find(collected, "tests/server/test_tile_states.py", "[sqlite]"),
        *_find(collected, "tests/server/test_process_lifecycle.py", "second_api"),
    ]
    for test in unit:
        assert not {"slow", "service", "browser"} & set(test["marks"]) and test["kept"]
