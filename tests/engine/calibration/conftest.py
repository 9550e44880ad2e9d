"""Recordings of blinking boards shared by the calibration tests (each made
once per session)."""

from __future__ import annotations

from pathlib import Path

import pytest
from calibration_recordings import Recording, record, write_events

from tectum.sources.simulate.blink_board import Board


@pytest.fixture(scope="session")
def dots() -> Recording:
    """A 7x5 symmetric dot grid, 8 views, 5 Hz/px of shot noise."""
    return record(Board(), noise_hz=5.0)


@pytest.fixture(scope="session")
def dots_file(dots: Recording, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_events(dots.events, tmp_path_factory.mktemp("calib") / "board.npz")
