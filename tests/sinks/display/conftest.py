"""A running live view for the display tests: a paced moving-bars pattern
(with flow columns) served at ``http://127.0.0.1:PORT``."""

from __future__ import annotations

import socket
import time
import urllib.request
from collections.abc import Iterator

import pytest

import tectum
from tectum.sinks.display.live import LiveViewSink


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def live_view(request: pytest.FixtureRequest) -> Iterator[str]:
    """The base URL of a live view whose first frame is ready; the fixture's
    parameter (``indirect=True``) is a dict of further LiveViewSink options."""
    port = free_port()
    p = tectum.Pipeline(pace=1.0)
    p.sink(LiveViewSink(f"http://127.0.0.1:{port}", fps=20, scale=2, **getattr(request, "param", {})),
           p.source("pattern:", sensor="96x64", duration_us=60_000_000, speed=40.0, period_px=32, bar_px=12,
                    noise_hz=0.0))
    th = tectum.ThreadedPipeline(p, watch=[]).start()
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if '"frames": 0' not in urllib.request.urlopen(base + "/stats.json", timeout=2).read().decode():
                break
        except OSError:
            pass
        time.sleep(0.05)
    yield base
    th.stop()
    th.join(60)
