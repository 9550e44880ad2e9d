"""Shared inputs for the filter tests: small generated streams, as fixtures
that return the generator functions."""

from __future__ import annotations

import numpy as np
import pytest

from tectum import EventPacket, concat
from tectum.sources.pattern import PatternSource


def pattern(sensor: str = "24x16", duration_us: int = 60_000, noise_hz: float = 50.0, speed: float = 400.0,
            seed: int = 0) -> EventPacket:
    """The ``pattern:`` source's moving bars with labelled noise, as one packet."""
    src = PatternSource(sensor=sensor, duration_us=duration_us, noise_hz=noise_hz, speed=speed, seed=seed,
                        window_us=5_000)
    return concat(list(src.packets()))  # type: ignore[return-value]


def poisson_noise(sensor: tuple[int, int], rate_hz: float, duration_us: int, seed: int = 0) -> EventPacket:
    """Pure Poisson noise: ``rate_hz`` events per pixel per second, random polarity."""
    rng = np.random.default_rng(seed)
    w, h = sensor
    n = rng.poisson(rate_hz * w * h * duration_us / 1e6)
    t = np.sort(rng.integers(0, duration_us, n))
    return EventPacket.from_arrays(t, rng.integers(0, w, n), rng.integers(0, h, n), rng.integers(0, 2, n),
                                   sensor=sensor, t_start=0, t_end=duration_us,
                                   columns={"noise": np.ones(n, np.uint8)})


@pytest.fixture
def make_pattern():  # type: ignore[no-untyped-def]
    return pattern


@pytest.fixture
def make_noise():  # type: ignore[no-untyped-def]
    return poisson_noise
