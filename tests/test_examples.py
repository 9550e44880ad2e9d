"""The examples run: the 1 kHz control loop on a short simulated rotation."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def test_control_loop_steers_on_the_latest_angular_velocity():
    spec = importlib.util.spec_from_file_location("control_loop", EXAMPLES / "control_loop.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    report = mod.main(["--duration-ms", "200"])
    assert report["estimates"] >= 3
    assert report["loop_hz"] > 200
    assert math.isfinite(report["latency_p50_ms"]) and report["latency_p99_ms"] >= report["latency_p50_ms"]
    assert abs(report["mean_rate_rad_s"] - math.sqrt(1.5 ** 2 + 2.5 ** 2 + 0.8 ** 2)) < 0.5
