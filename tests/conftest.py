"""Shared fixtures (helpers live in tests/helpers.py) and the suite's settings.

Hypothesis profiles: ``ci`` (the default) draws the same examples on every
run (``derandomize``), so a failure in CI is a real regression that repeats,
never a lucky draw; ``random`` (``TECTUM_HYPOTHESIS=random``) draws fresh
examples each run for nightly-style local bug hunting, and prints the blob
to reproduce what it finds.

Tests marked ``timing`` (they measure wall time, e.g. a 0.5 s control loop)
run after :func:`warm_kernels` has compiled, or loaded from numba's cache,
every kernel they call, so an empty cache never eats their time budget.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from tectum import EventPacket

from helpers import bars, shared_data

settings.register_profile(
    "ci", derandomize=True, database=None, max_examples=100, deadline=None, print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile(
    "random", derandomize=False, max_examples=100, deadline=None, print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
PROFILE = os.environ.get("TECTUM_HYPOTHESIS", "ci")
settings.load_profile(PROFILE)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "timing: measures wall time; runs after warm_kernels")


def pytest_report_header(config: pytest.Config) -> str:
    return f"hypothesis profile: {PROFILE} (TECTUM_HYPOTHESIS=random for fresh draws)"


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


@pytest.fixture(scope="session")
def warm_kernels() -> None:
    """Compile (or load from numba's cache) the kernels the timing tests call:
    a few ms of an emulated DAVIS240 over pyusb and of the pattern source,
    each through filter.refractory, run to the end without pacing."""
    import tectum
    from tectum.sources.usb.emulated import EmulatedBackend, EmulatedCamera
    from tectum.sources.usb.source import UsbSource
    from tectum.testing import ListSink

    cam = EmulatedCamera("davis240", realtime=False, duration_us=20_000, speed=50.0, noise_hz=0.5, window_us=1000)
    for src in (UsbSource("usb:", backend=EmulatedBackend(cam), timeout_ms=5, read_size=16384, idle_s=0.1),
                "pattern:"):
        p = tectum.Pipeline()
        s = p.source(src, sensor="64x48", duration_us=20_000, window_us=1000) if isinstance(src, str) else p.source(src)
        p.sink(ListSink(), p.op("filter.refractory", s, period_us=1000))
        tectum.run(p)


@pytest.fixture(autouse=True)
def _warm_before_timing(request: pytest.FixtureRequest) -> None:
    if request.node.get_closest_marker("timing") is not None:
        request.getfixturevalue("warm_kernels")
