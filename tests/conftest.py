"""Shared fixtures (helpers live in tests/helpers.py)."""

from __future__ import annotations

from pathlib import Path

import pytest

from tectum import EventPacket

from helpers import bars, shared_data


@pytest.fixture
def shared() -> Path:
    """The real recordings; skips the test where they are absent."""
    p = shared_data()
    if p is None:
        pytest.skip("real recordings not available: ../shared/data is absent (set TECTUM_SHARED_DATA)")
    return p


@pytest.fixture
def small_stream() -> EventPacket:
    return bars()
