"""Shared fixtures for the scan I/O tests: small random scans built in code."""

from __future__ import annotations

from pathlib import Path

import pytest

from jointseg.scan import Scan
from tests.support.scans import random_scan

#: Real scans shared between checkouts (never copied into the repository).
SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


@pytest.fixture
def scan() -> Scan:
    """A 500-point scan with rgb, labels and five fields."""
    return random_scan()


@pytest.fixture
def shared_data() -> Path:
    """The shared real-data folder; skips the test when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder {SHARED_DATA} is not present")
    return SHARED_DATA


@pytest.fixture
def make_scan():
    """Factory building random scans (keywords: :func:`tests.support.scans.random_scan`)."""
    return random_scan
