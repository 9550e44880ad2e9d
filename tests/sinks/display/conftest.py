"""A running live view for the display tests: a paced moving-bars pattern
(with flow columns) served at ``http://127.0.0.1:PORT``."""

from __future__ import annotations

import socket
import time
import urllib.request
from collections.abc import Callable, Iterator

import numpy as np
import pytest

import tectum
from tectum import MapPacket
from tectum.sinks.display.live import LiveViewSink
from tectum.testing import ListSource


def log_map(t: int, h: int = 40, w: int = 80, shift: float = 0.0) -> MapPacket:
    """A log-intensity map at ``t`` µs: a grating, its left quarter never observed (NaN)."""
    yy, xx = np.mgrid[0:h, 0:w]
    img = (np.sin(xx / 5.0 + shift) + 0.02 * yy).astype(np.float32)
    img[:, : w // 4] = np.nan
    return MapPacket([t], image=img[None], t_start=t, t_end=t + 1)


@pytest.fixture
def log_maps() -> Callable[[int], list[MapPacket]]:
    """``n`` -> that many maps of :func:`log_map`, 1 ms apart, each shifted."""
    return lambda n: [log_map(1000 * k, shift=k) for k in range(n)]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def live_view(request: pytest.FixtureRequest) -> Iterator[str]:
    """The base URL of a live view whose first frame is ready; the fixture's
    parameter (``indirect=True``) is a dict of further LiveViewSink options,
    and ``maps: True`` shows a minute of log-intensity maps (:func:`log_map`,
    ten a second) instead of the moving bars, ``op: NAME`` (with
    ``op_params``) the bars through that operator (a ``repr.*`` one: its frames)."""
    port = free_port()
    p = tectum.Pipeline(pace=1.0)
    opts = dict(getattr(request, "param", {}))
    if opts.pop("maps", False):
        source = p.source(ListSource([log_map(100_000 * k, shift=k) for k in range(600)]))
    else:
        source = p.source("pattern:", sensor="96x64", duration_us=60_000_000, speed=40.0, period_px=32, bar_px=12,
                          noise_hz=0.0)
        op = opts.pop("op", None)
        if op is not None:
            source = p.op(op, source, **opts.pop("op_params", {}))
    p.sink(LiveViewSink(f"http://127.0.0.1:{port}", fps=20, scale=2, **opts), source)
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
