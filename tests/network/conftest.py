"""Network test data (the random checkpoint ``random_weights`` lives in tests/conftest.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from jointseg.exceptions import Cancelled
from jointseg.synth import make_room


class StopAfter:
    """A cancel token that turns set after ``n`` checks, to reach checks inside a forward pass;
    ``check()`` is the same as a callback that raises."""

    def __init__(self, n: int) -> None:
        self.n, self.checks = n, 0

    def is_set(self) -> bool:
        self.checks += 1
        return self.checks > self.n

    def check(self) -> None:
        if self.is_set():
            raise Cancelled("cancelled by request")


@pytest.fixture
def stop_after() -> type[StopAfter]:
    """The :class:`StopAfter` token class."""
    return StopAfter


@pytest.fixture(scope="session")
def small_room():
    return make_room(1, points=30_000)


@pytest.fixture(scope="session")
def s3dis_fragment(shared_file) -> Path:
    """The real labelled S3DIS fragment; skips when ../shared is absent."""
    return shared_file("data/s3dis_fragment.ply")


@pytest.fixture(scope="session")
def dgcnn_model_1(shared_file) -> Path:
    """dgcnn.pytorch's S3DIS weights with Area 1 held out; skips when ../shared is absent."""
    return shared_file("models/dgcnn_s3dis/model_1.t7")
