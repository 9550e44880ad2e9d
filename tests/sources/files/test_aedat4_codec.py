"""The AEDAT 4.0 packet codec on its own: every packet kind tectum writes
(events, frames, IMU) through every compression and back, value by value;
damaged payloads (bytes overwritten, cut short) decode to a packet or raise
a ValueError (FlatError) naming the problem, never anything else; unknown
compressions and stream types are named."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FramePacket, ImuPacket, Packet
from tectum.sources.files import aedat4_codec as C

pytest.importorskip("lz4")
pytest.importorskip("zstandard")
SENSOR = (346, 260)


def packets() -> list[Packet]:
    rng = np.random.default_rng(11)
    n = 50
    t = np.sort(rng.integers(1 << 40, (1 << 40) + 10_000, n))
    ev = EventPacket.from_arrays(t, rng.integers(0, SENSOR[0], n), rng.integers(0, SENSOR[1], n),
                                 rng.choice([-1, 1], n), sensor=SENSOR)
    ts = np.array([100, 250, 900], np.int64)
    imu = ImuPacket(ts, accel=rng.normal(size=(3, 3)), gyro=rng.normal(size=(3, 3)), temperature=rng.normal(size=3))
    fr = FramePacket(ts[:2], images=rng.integers(0, 256, (2, 3, 5), dtype=np.uint8), exposure_start=ts[:2] - 10,
                     exposure_end=ts[:2] + 10)
    return [ev, imu, fr]


def same(a: Packet, b: Packet) -> None:
    assert type(a) is type(b)
    assert a.t.tolist() == b.t.tolist()
    if isinstance(a, EventPacket):
        for c in "xyp":
            assert getattr(a, c).tolist() == getattr(b, c).tolist(), c
    elif isinstance(a, ImuPacket):
        for c in ("accel", "gyro", "temperature"):
            np.testing.assert_allclose(b.data[c], a.data[c], rtol=1e-6, atol=1e-6, err_msg=c)  # float32 on disk
    else:
        assert np.array_equal(np.asarray(b.images).reshape(a.images.shape), a.images)
        for c in ("exposure_start", "exposure_end"):
            assert b.data[c].tolist() == a.data[c].tolist(), c


@pytest.mark.parametrize("compression", ["none", "lz4", "lz4_high", "zstd", "zstd_high", 0, 3])
def test_every_kind_through_every_compression(compression: str | int) -> None:
    for pkt in packets():
        got = [C.decode_packet(kind, payload, compression, SENSOR) for kind, payload in C.encode_packet(pkt, compression)]
        if isinstance(pkt, FramePacket):  # one payload per frame
            assert len(got) == len(pkt)
            for k, q in enumerate(got):
                same(_frame(pkt, k), q)
        else:
            assert len(got) == 1
            same(pkt, got[0])


def _frame(pkt: FramePacket, k: int) -> FramePacket:
    return FramePacket(pkt.t[k:k + 1], images=pkt.images[k:k + 1], exposure_start=pkt.data["exposure_start"][k:k + 1],
                       exposure_end=pkt.data["exposure_end"][k:k + 1])


@settings(max_examples=150, deadline=None)
@given(which=st.integers(0, 3), edits=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=6),
       cut=st.one_of(st.none(), st.integers(0, 10_000)), compression=st.sampled_from(["none", "lz4", "zstd"]))
def test_damaged_payloads_decode_or_are_named(which: int, edits: list[tuple[int, int]], cut: int | None,
                                              compression: str) -> None:
    pkts = packets()
    kind, payload = C.encode_packet(pkts[min(which, 2)], "none")[0]
    raw = bytearray(payload)
    for at, value in edits:
        raw[at % len(raw)] = value
    if cut is not None:
        raw = raw[:cut % (len(raw) + 1)]
    stored = C.compress(bytes(raw), compression) if which < 3 else bytes(raw)  # 3: not compressed as stated
    try:
        C.decode_packet(kind, stored, compression, SENSOR)
    except ValueError as e:  # FlatError is a ValueError
        assert str(e)


def test_unknown_compressions_and_types_are_named() -> None:
    with pytest.raises(ValueError, match="unknown AEDAT4 compression 'brotli'"):
        C.compression_code("brotli")
    with pytest.raises(ValueError, match="unknown AEDAT4 compression code 9"):
        C.compression_code(9)
    with pytest.raises(ValueError, match="unsupported AEDAT4 stream type 'POSE'"):
        C.decode_packet("POSE", b"", "none")
    with pytest.raises(ValueError, match="needs the sensor size"):
        C.decode_packet("EVTS", C.encode_events(packets()[0]), "none")
    with pytest.raises(ValueError, match="cannot store"):
        C.encode_packet(object(), "none")  # type: ignore[arg-type]
