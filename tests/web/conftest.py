"""Fixtures of the viewer tests: result files made by the real pipeline, and Debian's chromium."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from jointseg.pipeline import PipelineConfig
from jointseg.scan import Scan
from jointseg.synth import make_room
from tests.support.result_files import write_result

CHROMIUM = Path("/usr/bin/chromium")
#: Flags for headless chromium in a container: no sandbox, no GPU (SwiftShader renders WebGL),
#: nothing fetched from the network.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-dev-shm-usage",
    "--js-flags=--expose-gc",  # lets a test measure the page's heap after a collection
]


@pytest.fixture(scope="session")
def random_config(random_weights: Path) -> PipelineConfig:
    """The small random network: the tests of the viewer never need good labels."""
    return PipelineConfig.model_validate(
        {"network": {"weights": str(random_weights), "device": "cpu"}, "seed": 0}
    )


@pytest.fixture(scope="session")
def results(tmp_path_factory: pytest.TempPathFactory, random_config: PipelineConfig) -> Path:
    """A folder with two small results: ``labelled`` (ground truth) and ``unlabelled``."""
    folder = tmp_path_factory.mktemp("results")
    scan = make_room(3, points=4000)
    write_result(folder, "labelled", scan, random_config)
    bare = Scan(scan.xyz, scan.rgb)
    write_result(folder, "unlabelled", bare, random_config)
    return folder


@pytest.fixture(scope="session")
def jobs(tmp_path_factory: pytest.TempPathFactory, random_config: PipelineConfig) -> Path:
    """``room``: 30 k labelled points through the bundled network (many classes, objects and
    a room); ``bare``: 30 k points without ground truth through the random network."""
    folder = tmp_path_factory.mktemp("viewer_jobs")
    write_result(folder, "room", make_room(4, points=30_000), PipelineConfig(seed=0))
    scan = make_room(5, points=30_000)
    write_result(folder, "bare", Scan(scan.xyz, scan.rgb), random_config)
    return folder


@pytest.fixture(scope="session")
def viewer(jobs: Path) -> Iterator[Any]:
    """A viewer (no keys) on ``jobs``, shared by the viewer's browser tests."""
    from tests.support.viewer_pages import free_port
    from web.sources import DirectorySource
    from web.viewer import Viewer

    instance = Viewer(DirectorySource(jobs), port=free_port())
    try:
        yield instance
    finally:
        instance.stop()


@pytest.fixture(scope="session")
def artifacts() -> Path:
    """Where browser tests leave their screenshots ($PYTEST_ARTIFACTS or tests/artifacts)."""
    folder = Path(os.environ.get("PYTEST_ARTIFACTS") or Path(__file__).parents[1] / "artifacts")
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """Debian's headless chromium driven by Playwright (no browser is ever downloaded)."""
    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} is missing: install Debian's chromium (scripts/setup_system.sh)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        instance = playwright.chromium.launch(
            executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS
        )
        try:
            yield instance
        finally:
            instance.close()
