"""Network test data (the random checkpoint ``random_weights`` lives in tests/conftest.py)."""

from __future__ import annotations

import pytest

from jointseg.synth import make_room


@pytest.fixture(scope="session")
def small_room():
    return make_room(1, points=30_000)
