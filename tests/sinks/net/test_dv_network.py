"""The AEDAT 4.0 network stream against iniVation's dv-processing itself,
both ways, on 127.0.0.1.

dv-processing's blocking calls keep Python's GIL, so the dv side always runs
in a child process (its script is below); tectum runs in this process.
"""

from __future__ import annotations

import importlib.util
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

import tectum
from tectum.sinks.net.dv import DvNetSink
from tectum.sources.net.dv import DvNetSource
from tectum.testing import ListSink, ListSource

pytestmark = pytest.mark.skipif(importlib.util.find_spec("dv_processing") is None,
                                reason="dv-processing is not installed (pip install 'tectum[peers]')")
G = 9.80665

#: Reads a dv+tcp server with dv.io.NetworkReader and saves what it got.
DV_READ = r"""
import sys, time, numpy as np, dv_processing as dv
port, out = int(sys.argv[1]), sys.argv[2]
r = dv.io.NetworkReader("127.0.0.1", port)
ev, imu = [], []
t0 = last = time.monotonic()
while time.monotonic() - t0 < 20:
    b = r.getNextEventBatch() if r.isEventStreamAvailable() else None
    i = r.getNextImuBatch() if r.isImuStreamAvailable() else None
    if b is not None and len(b):
        ev.append(b.numpy()); last = time.monotonic()
    if i:
        imu += [(m.timestamp, m.temperature, m.accelerometerX, m.accelerometerY, m.accelerometerZ,
                 m.gyroscopeX, m.gyroscopeY, m.gyroscopeZ) for m in i]
        last = time.monotonic()
    if (b is None or not len(b)) and not i:
        if not r.isRunning() and time.monotonic() - last > 0.3:
            break
        time.sleep(0.001)
dt = [("timestamp", "<i8"), ("x", "<i2"), ("y", "<i2"), ("polarity", "u1")]
e = np.concatenate(ev) if ev else np.zeros(0, dt)
np.savez(out, t=e["timestamp"], x=e["x"], y=e["y"], p=e["polarity"], imu=np.array(imu, np.float64).reshape(-1, 8),
         size=np.array(r.getEventResolution() or (0, 0)))
"""

#: Serves events or IMU samples with dv.io.NetworkWriter, saving what it sent.
DV_WRITE = r"""
import sys, time, numpy as np, dv_processing as dv
port, kind, comp, out = int(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4]
if kind == "events":
    st = dv.io.Stream.EventStream(0, "events", "tectum_test", (64, 48))
else:
    st = dv.io.Stream.IMUStream(0, "imu", "tectum_test")
st.setCompression(getattr(dv.CompressionType, comp))
w = dv.io.NetworkWriter("127.0.0.1", port, st)
t0 = time.monotonic()
while w.getClientCount() < 1 and time.monotonic() - t0 < 10:
    time.sleep(0.005)
rng = np.random.default_rng(7)
t, sent = 1_000_000, []
for k in range(20):
    if kind == "events":
        batch = dv.EventStore()
        for i in range(200):
            t += int(rng.integers(0, 3))
            rec = (t, int(rng.integers(0, 64)), int(rng.integers(0, 48)), bool(rng.integers(0, 2)))
            batch.push_back(*rec)
            sent.append(rec[:3] + (int(rec[3]),))
        w.writeEvents(batch)
    else:
        v = dv.IMUPacket.ImuVector() if hasattr(dv.IMUPacket, "ImuVector") else []
        for i in range(5):
            t += 1000
            vals = np.float32(rng.normal(size=7)).tolist()
            v.append(dv.IMU(t, *vals, 0.0, 0.0, 0.0))
            sent.append([t] + vals)
        w.writeImu(v)
t0 = time.monotonic()
while w.getQueuedPacketCount() > 0 and time.monotonic() - t0 < 10:
    time.sleep(0.005)
time.sleep(0.3)
np.save(out, np.array(sent, np.float64 if kind == "imu" else np.int64))
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run_dv(script: str, *args: object) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", script, *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def finish(proc: subprocess.Popen) -> None:
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    assert proc.returncode == 0, err[-3000:]


def serve(packets: list, tmp_path, **kw) -> tuple[np.lib.npyio.NpzFile, DvNetSink]:
    """Serve ``packets`` from a tectum dv+tcp sink to dv's NetworkReader."""
    p = tectum.Pipeline()
    sink = DvNetSink("dv+tcp://127.0.0.1:0", wait_s=15, linger_s=0.3, **kw)
    p.sink(sink, p.source(ListSource(packets)))
    th = tectum.ThreadedPipeline(p, watch=[]).start()
    assert sink.ready.wait(60)
    reader = run_dv(DV_READ, sink.port, tmp_path / "got.npz")
    finish(reader)
    th.join(60)
    return np.load(tmp_path / "got.npz"), sink


def event_stream(n: int = 3000, seed: int = 0) -> tectum.EventPacket:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(0, 4, n)).astype(np.int64) + 5_000
    return tectum.EventPacket.from_arrays(t, rng.integers(0, 64, n), rng.integers(0, 48, n), rng.integers(0, 2, n),
                                          sensor=(64, 48))


@pytest.mark.parametrize("compression", ["none", "lz4", "zstd"])
def test_dv_reader_gets_every_event_from_the_tectum_sink(tmp_path, compression: str) -> None:
    ev = event_stream()
    got, sink = serve(list(ev.batches(700)), tmp_path, compression=compression, packet_events=256)
    assert tuple(got["size"]) == (64, 48)
    assert np.array_equal(got["t"], ev.t)
    assert np.array_equal(got["x"], ev.x) and np.array_equal(got["y"], ev.y)
    assert np.array_equal(got["p"], (ev.p > 0).astype(np.uint8))
    assert sink.counts["clients"] == 1 and sink.counts["dropped_clients"] == 0


def test_dv_reader_gets_imu_samples_from_the_tectum_sink(tmp_path) -> None:
    rng = np.random.default_rng(3)
    t = np.arange(10_000, 60_000, 1000, dtype=np.int64)
    imu = tectum.ImuPacket(t, accel=rng.normal(size=(len(t), 3)), gyro=rng.normal(size=(len(t), 3)),
                           temperature=rng.normal(30, 1, len(t)))
    got, _ = serve([event_stream(50), imu], tmp_path, stream="imu")
    m = got["imu"]
    assert np.array_equal(m[:, 0], t)
    # dv stores float32 g and degrees/s
    assert np.allclose(m[:, 2:5], imu.accel / G, rtol=1e-6, atol=1e-6)
    assert np.allclose(m[:, 5:8], np.rad2deg(imu.gyro), rtol=1e-6, atol=1e-5)
    assert np.allclose(m[:, 1], imu.temperature, rtol=1e-6)


def receive(kind: str, compression: str, tmp_path) -> tuple[list, np.ndarray, DvNetSource]:
    """Run dv's NetworkWriter (child process) and read it with the tectum source."""
    port = free_port()
    writer = run_dv(DV_WRITE, port, kind, compression, tmp_path / "sent.npy")
    src = DvNetSource(f"dv+tcp://127.0.0.1:{port}", connect_s=15)
    got = ListSink()
    p = tectum.Pipeline()
    p.sink(got, p.source(src))
    t0 = time.monotonic()
    tectum.run(p)
    assert time.monotonic() - t0 < 30
    finish(writer)
    return got.packets, np.load(tmp_path / "sent.npy"), src


@pytest.mark.parametrize("compression", ["NONE", "LZ4"])
def test_tectum_source_reads_events_from_the_dv_writer(tmp_path, compression: str) -> None:
    packets, sent, src = receive("events", compression, tmp_path)
    ev = tectum.concat([q for q in packets if isinstance(q, tectum.EventPacket)])
    assert ev.sensor == (64, 48)
    assert np.array_equal(ev.t, sent[:, 0])
    assert np.array_equal(ev.x, sent[:, 1]) and np.array_equal(ev.y, sent[:, 2])
    assert np.array_equal(ev.p, np.where(sent[:, 3] > 0, 1, -1))
    assert src.counts["events"] == len(sent) and src.counts["protocol_errors"] == 0


def test_tectum_source_reads_imu_from_the_dv_writer(tmp_path) -> None:
    packets, sent, _ = receive("imu", "ZSTD", tmp_path)
    imu = tectum.concat([q for q in packets if isinstance(q, tectum.ImuPacket)])
    assert np.array_equal(imu.t, sent[:, 0].astype(np.int64))
    assert np.array_equal(imu.temperature, sent[:, 1].astype(np.float32).astype(np.float64))
    assert np.array_equal(imu.accel, sent[:, 2:5].astype(np.float32).astype(np.float64) * G)
    assert np.array_equal(imu.gyro, np.deg2rad(sent[:, 5:8].astype(np.float32).astype(np.float64)))
