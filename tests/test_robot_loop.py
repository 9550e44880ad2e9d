"""The robot-loop example: a 1 kHz control thread reads the newest result
of a pipeline fed by a live (emulated USB) camera and prints the measured
end-to-end latency (camera capture -> control loop)."""

from __future__ import annotations

import time

import numpy as np
import pytest

import tectum
from tectum.sources.usb.emulated import EmulatedBackend, EmulatedCamera
from tectum.sources.usb.source import UsbSource

pytestmark = pytest.mark.timing  # kernels compiled before the 0.5 s loop (conftest's warm_kernels)


def control_loop(tp: tectum.ThreadedPipeline, node: str, capture_time, seconds: float = 0.5,
                 hz: float = 1000.0) -> tuple[int, list[float]]:
    """Run at ``hz`` for ``seconds``; returns (ticks, latencies in s) of each new result."""
    period, seen, lat, ticks = 1.0 / hz, None, [], 0
    t_next = time.monotonic()
    end = t_next + seconds
    while time.monotonic() < end and ticks < int(seconds * hz) + 1:
        got = tp.latest(node)
        if got is not None and got[0] is not seen:
            seen = got[0]
            if len(seen):
                lat.append(time.monotonic() - capture_time(int(seen.t[-1])))
        ticks += 1
        t_next += period
        time.sleep(max(0.0, t_next - time.monotonic()))
    return ticks, lat


def test_robot_loop_on_an_emulated_usb_camera() -> None:
    cam = EmulatedCamera("davis240", realtime=True, duration_us=5_000_000, speed=50.0, noise_hz=0.5, window_us=1000)
    p = tectum.Pipeline()
    src = p.source(UsbSource("usb:", backend=EmulatedBackend(cam), timeout_ms=5, read_size=16384))
    node = p.op("filter.refractory", src, period_us=1000)
    with tectum.ThreadedPipeline(p, watch=[node]) as tp:
        ticks, lat = control_loop(tp, node, lambda t_us: cam._wall0 + t_us / 1e6)
    assert ticks > 10 and lat, "the control loop saw no result"
    ms = np.array(lat) * 1e3
    print(f"\nrobot loop (emulated DAVIS240 over pyusb): {ticks} ticks, {len(lat)} new results, "
          f"end-to-end latency p50 {np.median(ms):.2f} ms, p99 {np.percentile(ms, 99):.2f} ms")
    assert np.all(ms > -5.0)  # results never come from the future (tolerance: wall-clock jitter)


@pytest.mark.parametrize("packet_us", [1000, 1_000_000])  # results flow within a long source packet too
def test_robot_loop_on_the_paced_pattern(packet_us: int) -> None:
    p = tectum.Pipeline(pace=1.0)
    src = p.source("pattern:", sensor="64x48", duration_us=3_000_000, window_us=packet_us)
    node = p.op("filter.refractory", src, period_us=1000)
    tp = tectum.ThreadedPipeline(p, watch=[node]).start()
    t0 = time.monotonic()
    try:
        ticks, lat = control_loop(tp, node, lambda t_us: t0 + t_us / 1e6, seconds=0.4)
    finally:
        tp.stop()
        tp.join(60)
    assert lat
    ms = np.array(lat) * 1e3
    print(f"\nrobot loop (paced pattern): {ticks} ticks, latency p50 {np.median(ms):.2f} ms")
