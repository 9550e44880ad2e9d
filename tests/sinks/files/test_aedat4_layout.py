"""The layout of the AEDAT 4.0 files tectum writes: event packets of
``packet_events`` events, each one LZ4 frame (64 KiB linked blocks, content
size, no checksums) compressed with the sink's LZ4 acceleration (3 unless
told), and readable event for event by dv-processing."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from tectum import EventPacket
from tectum.sinks.files._common import write_all
from tectum.sinks.files.aedat4 import DEFAULT_ACCELERATION, Aedat4Sink
from tectum.sources.files import aedat4_codec as codec

lz4_frame = pytest.importorskip("lz4.frame", reason="lz4 (the aedat4 extra) not installed")


def _events(n: int = 70_000) -> EventPacket:
    """Random pixels at sorted times: many short LZ4 matches, where the
    acceleration changes the compressed bytes."""
    rng = np.random.default_rng(3)
    return EventPacket.from_arrays(np.sort(rng.integers(0, 2_000_000, n)), rng.integers(0, 640, n),
                                   rng.integers(0, 480, n), rng.choice([-1, 1], n), sensor=(640, 480))


def _event_payloads(path: Path) -> list[bytes]:
    """The payloads of stream 0 (events), in file order."""
    buf = path.read_bytes()
    i = 18 + struct.unpack_from("<i", buf, 14)[0]
    out = []
    while i + 8 <= len(buf):
        sid, size = struct.unpack_from("<ii", buf, i)
        if sid == 0:
            out.append(buf[i + 8:i + 8 + size])
        i += 8 + size
    return out


@pytest.mark.parametrize("threads", [1, 2])
def test_event_packets_are_lz4_frames_at_the_default_acceleration(tmp_path: Path, threads: int) -> None:
    pkt = _events()
    f = tmp_path / "o.aedat4"
    write_all(Aedat4Sink(str(f), threads=threads), [pkt])  # an incoming packet is split, never merged
    payloads = _event_payloads(f)
    parts = list(pkt.batches(1 << 16))
    assert DEFAULT_ACCELERATION == 3
    assert [len(q) for q in parts] == [65_536, 4_464] and len(payloads) == 2
    for payload, part in zip(payloads, parts, strict=True):
        raw = codec.events_buffer(part)
        assert payload[:4] == b"\x04\x22\x4d\x18"  # LZ4 frame magic
        assert payload[4] == 0x48  # version 01, linked blocks, content size; no block or content checksum
        assert payload[5] == 0x40  # blocks of at most 64 KiB
        assert struct.unpack_from("<Q", payload, 6)[0] == len(raw)
        # acceleration 3 is lz4.frame's level -2 (LZ4F: acceleration = 1 - level)
        assert payload == lz4_frame.compress(raw, compression_level=-2, content_checksum=False)
        assert payload != lz4_frame.compress(raw, compression_level=0, content_checksum=False)
        assert lz4_frame.decompress(payload) == raw.tobytes()


def test_acceleration_1_writes_lz4s_default_frames(tmp_path: Path) -> None:
    pkt = _events(5_000)
    f = tmp_path / "o.aedat4"
    write_all(Aedat4Sink(str(f), acceleration=1, threads=1), [pkt])
    (payload,) = _event_payloads(f)
    assert payload == lz4_frame.compress(codec.events_buffer(pkt), compression_level=0, content_checksum=False)


def test_acceleration_below_1_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="acceleration"):
        Aedat4Sink(str(tmp_path / "o.aedat4"), acceleration=0)


def test_default_file_reads_back_in_dv_processing(tmp_path: Path) -> None:
    dv = pytest.importorskip("dv_processing", reason="dv-processing (peer) not installed")
    pkt = _events()
    f = tmp_path / "o.aedat4"
    write_all(Aedat4Sink(str(f)), list(pkt.batches(25_000)))
    rec = dv.io.MonoCameraRecording(str(f))
    parts = []
    while (b := rec.getNextEventBatch()) is not None:
        parts.append(b.numpy())
    ref = np.concatenate(parts)
    assert rec.getEventResolution() == (640, 480)
    assert np.array_equal(ref["timestamp"], pkt.t)
    assert np.array_equal(ref["x"], pkt.x) and np.array_equal(ref["y"], pkt.y)
    assert np.array_equal(np.where(ref["polarity"], 1, -1), pkt.p)
