"""Hostile input to the network receiver: rejected and counted, never fatal."""

from __future__ import annotations

import socket
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import tectum
from tectum.sources.net._wire import HEADER, Receiver, chunks, encode_end, encode_events, encode_hello
from tectum.sources.net.source import NetSource
from tectum.sources.pattern import moving_bars
from tectum.testing import ListSink

pytestmark = pytest.mark.abuse


def _stream(n_windows: int = 2) -> tuple[list[bytes], tectum.EventPacket]:
    rng = np.random.default_rng(1)
    pk = moving_bars(0, 20_000 * n_windows, sensor=(32, 24), speed=500.0, period_px=8, bar_px=3, noise_hz=5.0,
                     jitter_us=0.0, rng=rng)
    cols = [(k, pk.columns[k].dtype) for k in pk.columns]
    hello = encode_hello(7, 0, pk.sensor, cols)
    schema = zlib.crc32(hello[HEADER:])
    msgs, seq = [hello], 1
    for piece, a, b in chunks(pk, 50):
        msgs.append(encode_events(7, seq, schema, piece, a, b, list(pk.columns)))
        seq += 1
    msgs.append(encode_end(7, seq, schema, pk.t_end))
    return msgs, pk


def test_clean_stream_decodes_exactly() -> None:
    msgs, pk = _stream()
    r = Receiver()
    out = [q for m in msgs for q in r.feed(m)]
    got = tectum.concat(out)
    assert np.array_equal(got.t, pk.t) and np.array_equal(got.x, pk.x) and np.array_equal(got.p, pk.p)
    assert np.array_equal(got["vx"], pk["vx"], equal_nan=True)
    assert r.ended and r.lost == 0 and not r.rejected


def test_lost_and_duplicated_messages_are_counted() -> None:
    msgs, _ = _stream()
    r = Receiver()
    for i, m in enumerate(msgs):
        if i in (3, 4):
            continue  # lost on the way
        r.feed(m)
        if i == 6:
            r.feed(m)  # duplicated
    assert r.lost == 2 and r.late == 1 and r.ended


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_mutated_and_random_messages_never_crash(data: st.DataObject) -> None:
    msgs, _ = _stream(1)
    r = Receiver(max_held=1000)
    out: list[tectum.EventPacket] = []
    for m in msgs:
        kind = data.draw(st.sampled_from(["keep", "flip", "truncate", "random", "extend"]))
        b = bytearray(m)
        if kind == "flip" and b:
            i = data.draw(st.integers(0, len(b) - 1))
            b[i] ^= data.draw(st.integers(1, 255))
        elif kind == "truncate":
            b = b[: data.draw(st.integers(0, len(b)))]
        elif kind == "random":
            b = bytearray(data.draw(st.binary(max_size=200)))
        elif kind == "extend":
            b += data.draw(st.binary(min_size=1, max_size=50))
        out += r.feed(bytes(b))
    out += r.flush()
    for a, q in zip(out, out[1:]):  # whatever came out is a valid stream
        assert q.t_start >= a.t_end
    for q in out:
        q.validate()
    c = r.counts()
    assert c["accepted"] + c["rejected_total"] + c["late"] <= len(msgs) + 1


def test_hostile_tcp_sender_is_counted_and_the_source_survives() -> None:
    msgs, pk = _stream(1)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    src = NetSource(f"tcp://127.0.0.1:{port}", reconnect_s=2.0)
    p = tectum.Pipeline()
    sink = ListSink()
    p.sink(sink, p.source(src))
    th = tectum.ThreadedPipeline(p, watch=[]).start()
    assert src.ready.wait(60)

    def frame(m: bytes) -> bytes:
        return len(m).to_bytes(4, "little") + m

    with socket.create_connection(("127.0.0.1", port), timeout=5) as c:  # garbage first: not a sender
        c.sendall(frame(b"\x00" * 60))
    with socket.create_connection(("127.0.0.1", port), timeout=5) as c:  # a sender, then garbage in valid frames
        c.sendall(frame(msgs[0]) + frame(msgs[1][:-3]) + frame(b"TQ" + b"\xff" * 50))
        c.sendall((1 << 31).to_bytes(4, "little"))  # a 2 GiB frame: refused, connection dropped
    with socket.create_connection(("127.0.0.1", port), timeout=5) as c:  # the real sender reconnects
        c.sendall(b"".join(frame(m) for m in msgs))
        c.shutdown(socket.SHUT_WR)
        c.settimeout(5)
        c.recv(1)
    th.join(60)
    got = sink.events()
    assert np.array_equal(got.t, pk.t) and np.array_equal(got.y, pk.y)
    r = src.counts
    assert r["rejected_magic"] == 1 and r["rejected_length"] == 1 and r["rejected_version"] == 1
    assert r["dropped_first_message"] == 1 and r["dropped_length"] == 1 and r["dropped_connections"] == 2
