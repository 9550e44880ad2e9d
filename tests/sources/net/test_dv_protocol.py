"""The DV (AEDAT 4.0) network stream without dv-processing: tectum's sink to
tectum's source on loopback, and hostile bytes against the parser."""

from __future__ import annotations

import socket
import struct

import numpy as np
import pytest
import trio
from hypothesis import given, settings
from hypothesis import strategies as st

import tectum
from tectum.sinks.net.dv import DvNetSink
from tectum.sources.files import aedat4_codec as codec
from tectum.sources.net._dv import DvDecoder, DvParser, StreamDecl, io_header, packet_bytes, parse_header
from tectum.sources.net.dv import DvNetSource
from tectum.testing import ListSink, ListSource


def events(n: int = 2000, seed: int = 0, sensor=(64, 48)) -> tectum.EventPacket:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.integers(0, 3, n)).astype(np.int64)
    return tectum.EventPacket.from_arrays(t, rng.integers(0, sensor[0], n), rng.integers(0, sensor[1], n),
                                          rng.integers(0, 2, n), sensor=sensor)


def wire(pkts: list[tectum.EventPacket], comp: str = "none") -> bytes:
    head = io_header([StreamDecl(0, "events", (64, 48))], comp)
    return head + b"".join(packet_bytes(0, codec.compress(codec.encode_events(p), comp)) for p in pkts)


def decode_all(data: bytes, chunk: int) -> tuple[list[tectum.Packet], DvDecoder]:
    parser = DvParser(max_packet=1 << 20)
    dec: DvDecoder | None = None
    out: list[tectum.Packet] = []
    for i in range(0, len(data), chunk):
        for sid, payload in parser.feed(data[i:i + chunk]):
            if dec is None:
                dec = DvDecoder(parser.compression, parser.streams, {"events", "imu"})
            out += dec.decode(sid, payload)
    assert dec is not None
    return out + dec.flush(), dec


def test_header_round_trip() -> None:
    head = io_header([StreamDecl(3, "events", (346, 260), source="DAVIS346 & co")], "lz4")
    n = struct.unpack_from("<i", head)[0]
    assert n == len(head) - 4
    comp, streams = parse_header(head[4:])
    assert comp == 1 and streams[3].type_id == "EVTS" and streams[3].sensor == (346, 260)


@pytest.mark.parametrize("chunk", [1, 7, 4096])
def test_any_chunking_gives_the_events_with_no_split_timestamp(chunk: int) -> None:
    ev = events(600)
    pieces = [ev._take_slice(i, min(i + 97, len(ev)), int(ev.t[i]), int(ev.t[min(i + 97, len(ev)) - 1]) + 1)
              for i in range(0, len(ev), 97)]  # DV packets may split a run of equal timestamps
    out, dec = decode_all(wire(pieces, "lz4"), chunk)
    got = tectum.concat(out)
    assert np.array_equal(got.t, ev.t) and np.array_equal(got.x, ev.x) and np.array_equal(got.p, ev.p)
    for a, b in zip(out, out[1:]):
        assert a.t_end == b.t_start and (not len(a) or not len(b) or a.t[-1] < b.t[0])
    assert dec.counts["events"] == len(ev)


def test_hostile_packets_are_counted_not_fatal() -> None:
    ev = events(300)
    bad_xy = tectum.EventPacket.from_arrays(np.array([10**6]), np.array([100]), np.array([0]), np.array([1]),
                                            sensor=(2000, 2000))
    back = ev._take_slice(0, 10, int(ev.t[0]), int(ev.t[9]) + 1)  # goes back in time after ev
    payloads = [codec.encode_events(ev), codec.encode_events(bad_xy), codec.encode_events(back), b"\x00" * 40,
                codec.encode_events(ev)[:-20]]
    data = io_header([StreamDecl(0, "events", (64, 48))], "none")
    data += b"".join(packet_bytes(0, p) for p in payloads) + packet_bytes(9, b"xyz")
    out, dec = decode_all(data, 1000)
    assert np.array_equal(tectum.concat(out).t, ev.t)
    c = dec.counts
    assert c["rejected_bad_event"] == 1 and c["rejected_time"] == 1 and c["skipped"] == 1
    assert c.get("rejected_flatbuffer", 0) + c.get("rejected_corrupt", 0) == 2


def test_oversized_packet_or_header_is_refused_before_allocating() -> None:
    parser = DvParser(max_packet=1 << 16)
    with pytest.raises(ValueError, match="IOHeader length"):
        parser.feed(struct.pack("<i", 1 << 30))
    parser = DvParser(max_packet=1 << 16)
    parser.feed(io_header([StreamDecl(0, "events", (64, 48))], "none"))
    with pytest.raises(ValueError, match="packet size"):
        parser.feed(struct.pack("<ii", 0, 1 << 20))
    assert parser.pending <= 16


@settings(max_examples=40, deadline=None)
@given(st.binary(max_size=300), st.integers(0, 2000))
def test_random_bytes_never_crash(junk: bytes, cut: int) -> None:
    data = bytearray(wire([events(50)]))
    pos = min(cut, len(data) - 1)
    data[pos:pos + len(junk)] = junk
    parser = DvParser(max_packet=1 << 16)
    try:
        got = parser.feed(bytes(data))
    except ValueError:
        return  # framing refused: the source drops the connection and counts it
    if parser.streams is None:
        return
    try:
        dec = DvDecoder(parser.compression, parser.streams, {"events"})
    except ValueError:
        return
    for sid, payload in got:
        for pkt in dec.decode(sid, payload):
            pkt.validate()


def test_tectum_sink_to_tectum_source(tmp_path) -> None:
    ev = events(5000, seed=4)
    tx = tectum.Pipeline()
    sink = DvNetSink("dv+tcp://127.0.0.1:0", compression="zstd", wait_s=10, linger_s=0.0, packet_events=333)
    tx.sink(sink, tx.source(ListSource(list(ev.batches(1000)))))
    th = tectum.ThreadedPipeline(tx, watch=[]).start()
    assert sink.ready.wait(60)
    src = DvNetSource(f"dv+tcp://127.0.0.1:{sink.port}")
    got = ListSink()
    rx = tectum.Pipeline()
    rx.sink(got, rx.source(src))
    stats = tectum.run(rx)
    th.join(60)
    out = tectum.concat(got.packets)
    assert np.array_equal(out.t, ev.t) and np.array_equal(out.y, ev.y) and np.array_equal(out.p, ev.p)
    assert src.counts["events"] == len(ev)
    assert stats.as_dict()["nodes"]  # the source's counters reach the run's stats
    node = next(iter(stats.as_dict()["nodes"].values()))
    assert node["counters"]["events"] == len(ev)


def test_source_says_clearly_when_nothing_listens_or_it_is_not_dv() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    src = DvNetSource(f"dv+tcp://127.0.0.1:{port}", connect_s=0.1)
    with pytest.raises(tectum.TectumError, match="cannot connect"):
        trio.run(_drain, src)

    async def http_like(stream: trio.SocketStream) -> None:
        await stream.send_all(b"HTTP/1.1 200 OK\r\n\r\n" + b"x" * 64)

    async def main() -> None:
        async with trio.open_nursery() as n:
            lst = (await trio.open_tcp_listeners(0, host="127.0.0.1"))[0]
            n.start_soon(trio.serve_listeners, http_like, [lst])
            bad = DvNetSource(f"dv+tcp://127.0.0.1:{lst.socket.getsockname()[1]}")
            with pytest.raises(tectum.TectumError, match="IOHeader"):
                await _drain(bad)
            n.cancel_scope.cancel()

    trio.run(main)


async def _drain(src: DvNetSource) -> None:
    async for _ in src.apackets():
        pass
