"""IMU samples and APS frames over the network framing (TCP and UDP with
fragments), round trips on loopback, and hostile SAMPLES/FRAG messages."""

from __future__ import annotations

import socket
import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import tectum
from tectum import FramePacket, ImuPacket, Kind, PosePacket, TriggerPacket
from tectum.sinks.net.sink import NetSink
from tectum.sources.net._samples import FRAG, SAMPLES, encode_samples, schema_of
from tectum.sources.net._wire import HEADER, Receiver, _header
from tectum.sources.net.source import NetSource
from tectum.sources.usb.emulated import EmulatedBackend, EmulatedCamera
from tectum.sources.usb.source import UsbSource
from tectum.testing import ListSink


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def of_kind(sink: ListSink, kind: Kind) -> list:
    return [q for q in sink.packets if q.kind == kind and len(q)]


def camera_over(scheme: str) -> tuple[ListSink, ListSink, NetSource, NetSink]:
    """An emulated DAVIS346 (events, IMU, frames) sent through a network
    sink to a network source in another pipeline."""
    port = free_port(socket.SOCK_STREAM if scheme == "tcp" else socket.SOCK_DGRAM)
    src = NetSource(f"{scheme}://127.0.0.1:{port}", idle_s=20.0)  # ends on the END message; idle only as a safety net
    rx = tectum.Pipeline()
    got = ListSink()
    rx.sink(got, rx.source(src))
    th = tectum.ThreadedPipeline(rx, watch=[]).start()
    assert src.ready.wait(60)
    cam = EmulatedCamera("davis346", duration_us=70_000, speed=200.0, noise_hz=1.0)
    tx = tectum.Pipeline()
    s = tx.source(UsbSource("usb:", backend=EmulatedBackend(cam), idle_s=0.1, frame_interval_us=20_000))
    sink = NetSink(f"{scheme}://127.0.0.1:{port}", rate_mev_s=0.3)
    truth = ListSink()
    tx.sink(sink, s)
    tx.sink(truth, s)
    tectum.run(tx)
    th.join(40)
    return truth, got, src, sink


def same_samples(a: list, b: list) -> None:
    ca, cb = tectum.concat(a), tectum.concat(b)
    assert np.array_equal(ca.t, cb.t)
    assert set(ca.data) == set(cb.data)
    for k in ca.data:
        assert ca.data[k].dtype == cb.data[k].dtype and np.array_equal(ca.data[k], cb.data[k]), k


def test_tcp_carries_events_imu_and_frames() -> None:
    truth, got, src, _ = camera_over("tcp")
    assert src.counts["rejected_total"] == 0 and src.counts["lost"] == 0
    assert np.array_equal(got.events().t, truth.events().t)
    for kind in (Kind.IMU, Kind.FRAMES):
        assert of_kind(truth, kind)
        same_samples(of_kind(truth, kind), of_kind(got, kind))


def test_udp_fragments_frames_and_keeps_datagrams_under_the_mtu() -> None:
    truth, got, src, sink = camera_over("udp")
    c = src.counts
    assert c["lost"] == 0 and c["rejected_total"] == 0 and c["fragments_incomplete"] == 0
    frames = of_kind(truth, Kind.FRAMES)
    assert frames and frames[0].images[0].nbytes > 50 * sink.datagram  # many fragments per frame
    same_samples(frames, of_kind(got, Kind.FRAMES))
    same_samples(of_kind(truth, Kind.IMU), of_kind(got, Kind.IMU))
    assert np.array_equal(got.events().x, truth.events().x)


def message(pkt, seq: int = 0, session: int = 7) -> bytes:
    tb = int(pkt.t[0]) if len(pkt) else pkt.t_start
    return encode_samples(_header(SAMPLES, session, seq, schema_of(pkt), pkt.t_start, pkt.t_end, tb, len(pkt)),
                          pkt, tb)


def test_every_sample_kind_round_trips_through_the_receiver() -> None:
    rng = np.random.default_rng(0)
    pkts = [PosePacket(np.array([5, 9]), t_start=0, t_end=10, position=rng.normal(size=(2, 3)),
                       orientation=rng.normal(size=(2, 4)).astype(np.float32)),
            TriggerPacket(np.array([3, 3, 8]), t_start=0, t_end=20, channel=np.array([0, 1, 0], np.int16),
                          value=np.array([1, 0, 1], np.uint8)),
            FramePacket(np.array([15]), t_start=10, t_end=16, images=rng.integers(0, 255, (1, 5, 4, 3), np.uint8)),
            ImuPacket(np.empty(0, np.int64), t_start=0, t_end=4, accel=np.empty((0, 3)), gyro=np.empty((0, 3)))]
    r = Receiver()
    out = [q for i, p in enumerate(pkts) for q in r.feed(message(p, seq=i))]
    assert [type(q) for q in out] == [type(p) for p in pkts] and r.rejected == {}
    for a, b in zip(pkts, out):
        assert (a.t_start, a.t_end) == (b.t_start, b.t_end) and np.array_equal(a.t, b.t)
        assert all(np.array_equal(a.data[k], b.data[k]) and a.data[k].dtype == b.data[k].dtype for k in a.data)


def test_fragments_out_of_place_are_rejected_and_counted() -> None:
    img = FramePacket(np.array([100]), t_start=0, t_end=101, images=np.zeros((1, 40, 40), np.uint8))
    whole = message(img, seq=1)
    parts = [whole[i:i + 500] for i in range(0, len(whole), 500)]

    def frag(i: int, seq: int = 1, total: int = len(whole), crc: int | None = None) -> bytes:
        return _header(FRAG, 7, seq, zlib.crc32(parts[i]) if crc is None else crc, i, len(parts), total,
                       len(parts[i])) + parts[i]

    r = Receiver(max_message=1 << 16)
    assert r.feed(frag(0)) == [] and r.feed(frag(1, crc=1)) == [] and r.rejected == {"fragment": 1}
    assert r.feed(frag(0, seq=2)) == [] and r._frag.incomplete == 1  # another message began: the partial is gone
    assert r.feed(frag(0, total=1 << 30)) == [] and r.rejected["fragment"] == 2  # over max_message: nothing allocated
    r2 = Receiver()
    got = [q for i in range(len(parts)) for q in r2.feed(frag(i))]
    assert len(got) == 1 and np.array_equal(got[0].images, img.images)


@pytest.mark.abuse
@settings(max_examples=60, deadline=None)
@given(st.data())
def test_mutated_samples_messages_never_crash_or_overallocate(data) -> None:
    imu = ImuPacket(np.array([10, 20, 30]), t_start=0, t_end=40, accel=np.ones((3, 3)), gyro=np.zeros((3, 3)),
                    temperature=np.array([20.0, 21.0, 22.0]))
    msg = bytearray(message(imu))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(msg) - 1))
        msg[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(HEADER - 2, len(msg)))
    r = Receiver(max_events=1000)
    out = r.feed(bytes(msg[:cut]))
    assert len(out) + sum(r.rejected.values()) == 1
    for q in out:
        q.validate()
        assert sum(a.nbytes for a in q.data.values()) <= len(msg)


def test_header_struct_matches_the_documented_44_bytes() -> None:
    assert HEADER == 44 == struct.calcsize("<2sBBIIIqqqI")
