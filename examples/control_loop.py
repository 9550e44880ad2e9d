"""A 1 kHz control loop steering on the camera's angular velocity.

A simulated camera turns before a textured panorama; ``tracker.angular_velocity``
runs in a :class:`tectum.ThreadedPipeline` (replayed in real time, so events
arrive when they are due) and the loop below, at ``rate_hz``, reads the
newest estimate with ``latest()`` (never blocking) and drives a gimbal that
counter-rotates the camera: a proportional command on the measured ω, the
gimbal integrating it. It reports the event-to-estimate latency (from the
wall time the window's last event was due to the time its estimate was
produced) and how well the gimbal cancelled the rotation.

    python examples/control_loop.py --duration-ms 500
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

import tectum


def pipeline(omega: tuple[float, float, float], duration_us: int, sensor: tuple[int, int] = (120, 90),
             window_events: int = 8_000, step_events: int = 2_000) -> tectum.Pipeline:
    """Simulated rotation (computed first: the simulator is slower than real
    time) replayed in real time in 1 ms packets into the angular-velocity
    tracker (node id ``omega``). The simulator's default field of view is 60°."""
    from tectum.sources.simulate import simulate
    from tectum.testing import ListSource

    w, h = sensor
    f = (w / 2) / math.tan(math.radians(30))
    scene = {"panorama": {"texture": {"kind": "noise", "size": 256, "blur": 1.5, "contrast": 0.6, "mean": 0.35},
                          "texel_deg": 360 / 1024},
             "motion": {"angular_velocity": list(omega)}}
    ev, _truth = simulate(scene, duration_us, sensor=sensor, c_on=0.4, c_off=0.4)
    ev = tectum.EventPacket.from_arrays(ev.t, ev.x, ev.y, ev.p, sensor=sensor, t_start=0, t_end=duration_us)
    p = tectum.Pipeline(pace=1.0)
    cam = p.source(ListSource([ev.slice_time(t, t + 1_000) for t in range(0, duration_us, 1_000)]), id="cam")
    p.op("tracker.angular_velocity", cam, id="omega", calib=f"{f};{f};{(w - 1) / 2};{(h - 1) / 2}",
         window_events=window_events, step_events=step_events)
    return p


def control_loop(live: tectum.ThreadedPipeline, t0_wall: float, rate_hz: float = 1000.0,
                 gain: float = 1.0) -> dict[str, float]:
    """Run the loop until the pipeline ends; returns latency percentiles (ms),
    the loop's achieved rate (Hz) and the mean residual rotation rate (rad/s)."""
    period = 1.0 / rate_hz
    gimbal = np.zeros(3)  # gimbal rate command, rad/s (a real loop sends it to the motors here)
    seen: set[int] = set()
    latencies, residual = [], []
    ticks = 0
    next_tick = time.monotonic()
    while not live.done:
        got = live.latest("omega")
        if got is not None:
            pkt, produced = got
            if len(pkt) and int(pkt.t[-1]) not in seen:
                new = [int(t) for t in pkt.t if int(t) not in seen]
                seen.update(new)
                # from when each window's last event was due to when its estimate came out
                latencies += [produced - (t0_wall + t * 1e-6) for t in new]
                w = np.array([pkt["wx"][-1], pkt["wy"][-1], pkt["wz"][-1]])
                gimbal = -gain * w  # counter-rotate at the measured rate
                residual.append(float(np.linalg.norm(w)))
        ticks += 1
        next_tick += period
        time.sleep(max(0.0, next_tick - time.monotonic()))
    lat = np.array(latencies) * 1e3
    return {"estimates": len(latencies), "loop_hz": ticks / max(time.monotonic() - t0_wall, 1e-9),
            "latency_p50_ms": float(np.percentile(lat, 50)) if len(lat) else math.nan,
            "latency_p99_ms": float(np.percentile(lat, 99)) if len(lat) else math.nan,
            "mean_rate_rad_s": float(np.mean(residual)) if residual else math.nan,
            "last_command_rad_s": float(np.linalg.norm(gimbal))}


def main(argv: list[str] | None = None) -> dict[str, float]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration-ms", type=int, default=500)
    ap.add_argument("--rate-hz", type=float, default=1000.0)
    ap.add_argument("--omega", type=float, nargs=3, default=(1.5, -2.5, 0.8), help="camera rotation, rad/s")
    a = ap.parse_args(argv)
    p = pipeline(tuple(a.omega), a.duration_ms * 1000)
    live = tectum.ThreadedPipeline(p, watch=["omega"])
    with live:
        t0 = time.monotonic()  # stream time 0 is released about now
        report = control_loop(live, t0, a.rate_hz)
    print(f"{report['estimates']} estimates; loop at {report['loop_hz']:.0f} Hz; event-to-estimate latency "
          f"p50 {report['latency_p50_ms']:.1f} ms, p99 {report['latency_p99_ms']:.1f} ms; "
          f"measured |ω| {report['mean_rate_rad_s']:.2f} rad/s (true {np.linalg.norm(a.omega):.2f})")
    return report


if __name__ == "__main__":
    main()
