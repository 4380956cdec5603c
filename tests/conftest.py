"""Fixtures shared by every test package."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import torch

from jointseg.network.dgcnn.model import DGCNN
from jointseg.network.randlanet.checkpoint import save_checkpoint
from jointseg.network.randlanet.model import RandLANet, RandLANetConfig
from jointseg.training.config import TrainConfig

#: Real scans and published weights shared between checkouts (never copied into the repository).
SHARED = Path(__file__).resolve().parents[1].parent / "shared"
#: Environment variable naming the folder of the tests' weights files (not a service setting).
TEST_WEIGHTS_ENV = "JOINTSEG_TEST_WEIGHTS_DIR"

#: Fixtures that drive Debian's chromium: a test using one is marked ``browser``.
BROWSER_FIXTURES = frozenset({"browser"})
#: Fixtures that start processes (``jointseg serve``, a viewer's server) or talk to PostgreSQL
#: or Redis: a test using one is marked ``service``. Tests that start a service in their own
#: body carry ``@pytest.mark.service`` themselves.
SERVICE_FIXTURES = frozenset(
    {
        "service",  # tests/conftest.py, and test_service_browser's own
        "locked",  # tests/server/conftest.py, and test_viewer_tools_browser's own
        "postgres_url",
        "redis_queue",
        "bare",  # test_missing_weights: a service without weights
        "killed_run",  # test_tiled_jobs: a service whose worker is killed mid-run
        "viewer",  # tests/web/conftest.py
        "capped",  # test_big_result: a viewer with a small point cap
        "views",  # test_viewer_views_browser: a viewer with a pictures folder
    }
)


def pytest_configure(config: pytest.Config) -> None:
    """Pulled weights go to a throw-away cache: no test reads or fills the user's own."""
    import os
    import tempfile

    os.environ["JOINTSEG_CACHE"] = tempfile.mkdtemp(prefix="jointseg-cache-")
    # the one folder of test weights: the services the tests start allow it (weights_dirs)
    os.environ[TEST_WEIGHTS_ENV] = tempfile.mkdtemp(prefix="jointseg-weights-")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Marks ``browser`` and ``service`` tests by the fixtures they use, so that a new test is
    sorted without anyone remembering to mark it (``make test-fast`` leaves both out)."""
    for item in items:
        names = set(getattr(item, "fixturenames", ()))
        if names & BROWSER_FIXTURES or item.path.name.endswith("_browser.py"):
            item.add_marker(pytest.mark.browser)
        params = getattr(getattr(item, "callspec", None), "params", {})
        on_postgres = any(isinstance(v, str) and v == "postgres" for v in params.values())
        if names & SERVICE_FIXTURES or on_postgres:
            item.add_marker(pytest.mark.service)


def pytest_unconfigure(config: pytest.Config) -> None:
    import os
    import shutil

    shutil.rmtree(os.environ.get("JOINTSEG_CACHE", ""), ignore_errors=True)
    shutil.rmtree(os.environ.get(TEST_WEIGHTS_ENV, ""), ignore_errors=True)


def weights_folder() -> Path:
    """The folder the weights fixtures write to, and the test services' weights folder."""
    import os

    return Path(os.environ[TEST_WEIGHTS_ENV])


@pytest.fixture(scope="session")
def shared_file() -> Callable[[str], Path]:
    """``shared_file("data/x.ply")``: a path under ../shared; skips when it is absent."""

    def find(relative: str) -> Path:
        path = SHARED / relative
        if not path.exists():
            pytest.skip(f"{path} is not present")
        return path

    return find


@pytest.fixture(scope="session")
def random_weights() -> Path:
    """A small, randomly initialised RandLA-Net checkpoint: the tests never need trained weights."""
    torch.manual_seed(0)
    model = RandLANet(RandLANetConfig(num_points=4096))
    path = weights_folder() / "random.pt"
    save_checkpoint(path, model, {"data": "random initialisation (tests)"})
    return path


@pytest.fixture(scope="session")
def dgcnn_random_weights() -> Path:
    """A randomly initialised DGCNN saved as dgcnn.pytorch saves its S3DIS weights: a state dict
    from ``nn.DataParallel`` (``module.`` prefix), with batch-norm statistics that are not the
    identity, so that folding them is tested."""
    torch.manual_seed(0)
    model = DGCNN()
    for module in model.modules():
        if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
            module.running_mean.uniform_(-0.2, 0.2)
            module.running_var.uniform_(0.5, 2.0)
            module.weight.data.uniform_(-1.5, 1.5)  # negative scales too
            module.bias.data.uniform_(-0.2, 0.2)
    path = weights_folder() / "model_9.t7"
    torch.save({f"module.{k}": v for k, v in model.state_dict().items()}, path)
    return path


@pytest.fixture
def tiny_training(tmp_path: Path) -> Callable[..., TrainConfig]:
    """A factory of training configurations small enough for a test (a few steps on one small
    room); keyword arguments override the defaults."""

    def make(**overrides: Any) -> TrainConfig:
        base: dict[str, Any] = dict(
            out=tmp_path / "m.pt",
            epochs=1,
            steps_per_epoch=2,
            batch_size=1,
            num_points=2048,
            synth_rooms=1,
            synth_floors=0,
            val_rooms=1,
            synth_points=20_000,
            threads=1,
        )
        return TrainConfig(**{**base, **overrides})

    return make


@pytest.fixture(scope="session")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """The job service's embedded default (`jointseg serve`: SQLite table and queue, two
    workers, API key ``key-one``) in subprocesses, shared by the server and CLI tests."""
    from tests.support.service_process import running

    with running(tmp_path_factory.mktemp("service"), workers=2, api_keys="key-one") as svc:
        yield svc
