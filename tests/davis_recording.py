"""A small DAVIS-like recording for the tests of streams beside the events:
events, APS frames, IMU samples and triggers (``from davis_recording import
davis_packets, write_davis``; ``tests`` is on the path)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import tectum
from tectum import EventPacket, FramePacket, ImuPacket, Packet, TriggerPacket
from tectum.sinks.files._common import write_all
from tectum.sinks.npz import NpzSink

SENSOR = (34, 26)


def davis_packets(duration_us: int = 200_000, events: int = 3000, seed: int = 0) -> list[Packet]:
    """``duration_us`` of a DAVIS-like stream from t = 1 s: random events in
    packets of 10 ms, a uint8 frame every 20 ms (with exposure times), IMU
    at 1 kHz (with temperature) and a rising/falling trigger pair every 25 ms,
    interleaved by time as a file source gives them."""
    rng = np.random.default_rng(seed)
    t0, t1 = 1_000_000, 1_000_000 + duration_us
    t = np.sort(rng.integers(t0, t1, events))
    ev = EventPacket.from_arrays(t, rng.integers(0, SENSOR[0], events), rng.integers(0, SENSOR[1], events),
                                 rng.choice([-1, 1], events), sensor=SENSOR, t_start=t0, t_end=t1)
    tf = np.arange(t0 + 5000, t1, 20_000)
    frames = FramePacket(tf, images=rng.integers(0, 256, (len(tf), SENSOR[1], SENSOR[0]), dtype=np.uint8),
                         exposure_start=tf - 2000, exposure_end=tf + 2000, t_start=t0, t_end=t1)
    ti = np.arange(t0, t1, 1000)
    imu = ImuPacket(ti, accel=rng.normal(0, 1, (len(ti), 3)), gyro=rng.normal(0, 0.1, (len(ti), 3)),
                    temperature=rng.normal(30, 1, len(ti)), t_start=t0, t_end=t1)
    tt = np.repeat(np.arange(t0 + 1000, t1, 25_000), 2) + np.tile([0, 500], len(range(t0 + 1000, t1, 25_000)))
    trig = TriggerPacket(tt, channel=np.zeros(len(tt), np.int64), value=np.tile([1, 0], len(tt) // 2),
                         t_start=t0, t_end=t1)
    return list(tectum.interleave(_by_time(ev, 10_000), [[frames], [imu], [trig]]))


def _by_time(ev: EventPacket, step_us: int) -> list[EventPacket]:
    return [ev.slice_time(a, min(a + step_us, ev.t_end)) for a in range(ev.t_start, ev.t_end, step_us)]


def write_davis(path: Path, **kw: int) -> list[Packet]:
    """Write :func:`davis_packets` to ``path`` (.npz) and return them."""
    packets = davis_packets(**kw)
    write_all(NpzSink(str(path)), packets)
    return packets


def counts(packets: list[Packet]) -> dict[str, int]:
    """Rows by kind."""
    out: dict[str, int] = {}
    for p in packets:
        out[str(p.kind)] = out.get(str(p.kind), 0) + len(p)
    return out
