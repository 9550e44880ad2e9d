"""Hostile peers against the network receiver, on loopback (issue 20, item 16).

Receiver and peers run in one trio run on a MockClock that jumps over
every wait, so timeouts of seconds cost nothing; a peer is a plain trio
socket speaking the wire format (the real sender's messages come from the
encoder the sink uses)."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
import zlib
from collections.abc import Awaitable, Callable

import numpy as np
import pytest
import trio
import trio.testing

import tectum
from tectum.sources.net._auth import auth, nonce_of
from tectum.sources.net._wire import END, EVENTS, HEADER, _header, chunks, encode_end, encode_events, encode_hello
from tectum.sources.net.source import NetSource
from tectum.sources.pattern import moving_bars

pytestmark = pytest.mark.abuse

Peer = Callable[[int], Awaitable[None]]


def stream(session: int, sensor: tuple[int, int] = (32, 24)) -> tuple[list[bytes], tectum.EventPacket]:
    """A sender's messages (HELLO, EVENTS..., END) and the events they carry."""
    pk = moving_bars(0, 40_000, sensor=sensor, speed=500.0, period_px=8, bar_px=3, noise_hz=5.0, jitter_us=0.0,
                     rng=np.random.default_rng(session))
    hello = encode_hello(session, 0, pk.sensor, [(k, pk.columns[k].dtype) for k in pk.columns])
    schema = zlib.crc32(hello[HEADER:])
    msgs = [hello] + [encode_events(session, i + 1, schema, piece, a, b, list(pk.columns))
                      for i, (piece, a, b) in enumerate(chunks(pk, 50))]
    return msgs + [encode_end(session, len(msgs), schema, pk.t_end)], pk


def frame(m: bytes) -> bytes:
    return len(m).to_bytes(4, "little") + m


def receive(src: NetSource, *peers: Peer) -> tectum.EventPacket | None:
    """Run the source with the peers (each started once it listens) on a
    jumping clock; its events (None: no event packet). Fails if the run
    does not end within 10 min of (virtual) time."""
    got: list[tectum.Packet] = []

    async def main() -> None:
        with trio.fail_after(600):
            async with trio.open_nursery() as n:
                async def consume() -> None:
                    async for q in src.apackets():
                        got.append(q)
                    n.cancel_scope.cancel()  # the run is over: peers still talking are cut off

                n.start_soon(consume)
                while not src.ready.is_set():
                    await trio.sleep(0.01)
                for peer in peers:
                    n.start_soon(peer, src.port)

    trio.run(main, clock=trio.testing.MockClock(autojump_threshold=0))
    ev = [q for q in got if isinstance(q, tectum.EventPacket)]
    for a, b in zip(got, got[1:]):
        assert type(a) is not type(b) or b.t_start >= a.t_end
    return tectum.concat(ev) if ev else None


def sender(msgs: list[bytes], after_s: float = 0.0, secret: bytes = b"", session: int = 0,
           pause_s: float = 0.0) -> Peer:
    """A peer sending ``msgs`` after ``after_s`` s (``pause_s`` s apart),
    then waiting until the receiver closes."""

    async def peer(port: int) -> None:
        await trio.sleep(after_s)
        s = await trio.open_tcp_stream("127.0.0.1", port)
        async with s:
            if secret:
                head = b""
                while len(head) < 4 + HEADER + 16:
                    got = await s.receive_some(4 + HEADER + 16 - len(head))
                    assert got, "closed before the challenge"
                    head += got
                nonce = nonce_of(head[4:])
                assert nonce is not None
                await s.send_all(frame(auth(secret, nonce, session)))
            if pause_s:
                for m in msgs:
                    await s.send_all(frame(m))
                    await trio.sleep(pause_s)
            else:
                await s.send_all(b"".join(frame(m) for m in msgs))
            try:
                while await s.receive_some(1 << 16):
                    pass
            except trio.BrokenResourceError:
                pass

    return peer


def same(got: tectum.EventPacket | None, pk: tectum.EventPacket) -> None:
    assert got is not None and len(got) == len(pk)
    assert np.array_equal(got.t, pk.t) and np.array_equal(got.x, pk.x) and np.array_equal(got.p, pk.p)


def url() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{s.getsockname()[1]}"


def test_a_bare_connect_and_close_does_not_end_the_run() -> None:
    msgs, pk = stream(7)

    async def knock(port: int) -> None:
        s = await trio.open_tcp_stream("127.0.0.1", port)
        await s.aclose()

    src = NetSource(url())
    same(receive(src, knock, sender(msgs, after_s=5.0)), pk)  # the old receiver had stopped after 2 s
    c = src.counts
    assert c["dropped_closed"] == 1 and c["senders"] == 1 and c["finished"] == 1


def test_a_slowloris_is_dropped_after_the_timeout_while_the_sender_is_served() -> None:
    msgs, pk = stream(7)
    dropped_at: list[float] = []

    async def slowloris(port: int) -> None:
        s = await trio.open_tcp_stream("127.0.0.1", port)
        t0 = trio.current_time()
        async with s:
            try:
                await s.send_all((1000).to_bytes(4, "little"))  # a valid length, then a byte a second
                while True:
                    await trio.sleep(1.0)
                    await s.send_all(b"T")
            except (trio.BrokenResourceError, OSError):
                dropped_at.append(trio.current_time() - t0)

    src = NetSource(url(), timeout_s=5.0)
    assert len(msgs) * 0.5 > 10.0  # the sender is still sending when the slowloris is dropped
    same(receive(src, slowloris, sender(msgs, after_s=0.5, pause_s=0.5)), pk)
    assert src.counts["dropped_timeout"] == 1
    assert len(dropped_at) == 1 and 5.0 <= dropped_at[0] < 7.0  # noticed at its next byte after the close


@pytest.mark.parametrize("merge", [False, True])
def test_a_hostile_hello_of_another_schema_does_not_affect_the_sender(merge: bool) -> None:
    msgs, pk = stream(7)
    hostile, _ = stream(9, sensor=(1, 1))
    src = NetSource(url(), merge=merge, timeout_s=5.0)
    same(receive(src, sender(hostile[:1]), sender(msgs, after_s=1.0)), pk)  # its HELLO, then it idles
    assert src.counts["finished"] == 1 and src.counts["rejected_total"] == 0


def _far_tick(session: int) -> list[bytes]:
    """A valid HELLO of the sender's schema and an empty EVENTS message whose
    watermark is 2^61 µs (73,000 years)."""
    msgs, _ = stream(7)
    hello = bytearray(msgs[0])
    hello[4:8] = session.to_bytes(4, "little")
    schema = zlib.crc32(msgs[0][HEADER:])
    return [bytes(hello), _header(EVENTS, session, 1, schema, 0, 1 << 61, 0, 0)]


def test_a_far_watermark_from_one_peer_does_not_make_the_senders_messages_late() -> None:
    """The hostile speaks first, without the secret: it is never a sender."""
    msgs, pk = stream(7)
    src = NetSource(url(), secret="s3cret")
    got = receive(src, sender(_far_tick(9)), sender(msgs, after_s=1.0, secret=b"s3cret", session=7))
    same(got, pk)
    c = src.counts
    assert c["late"] == 0 and c["behind"] == 0 and c["dropped_auth"] == 1
    assert got is not None and got.t_end < 1 << 40


def test_merged_senders_keep_their_own_time() -> None:
    """With merge=true a peer's far watermark holds nobody back and makes
    nothing late: both streams come out merged by time."""
    msgs, pk = stream(7)
    msgs2, pk2 = stream(8)
    far = _far_tick(9)
    src = NetSource(url(), merge=True, senders=2)
    got = receive(src, sender(msgs, pause_s=0.1), sender(msgs2, after_s=0.01, pause_s=0.1),
                  sender(far, after_s=0.5))
    want = tectum.merge([pk, pk2], 0, pk.t_end)
    assert got is not None and len(got) == len(pk) + len(pk2)
    assert np.array_equal(got.t, want.t) and np.array_equal(np.sort(got.x), np.sort(want.x))
    assert src.counts["late"] == 0 and src.counts["behind"] == 0


def test_a_forged_end_without_the_secret_does_not_end_the_run() -> None:
    msgs, pk = stream(7)
    forged = encode_end(7, 99, zlib.crc32(msgs[0][HEADER:]), 1000)
    empty_end = _header(END, 9, 0, 0, 1000, 1000, 1000, 0)  # "a stream without events"
    src = NetSource(url(), secret="s3cret")
    got = receive(src, sender([forged]), sender([empty_end], after_s=0.2),
                  sender(msgs, after_s=1.0, secret=b"s3cret", session=7))
    same(got, pk)
    assert src.counts["dropped_auth"] == 2 and src.counts["finished"] == 1


def test_a_wrong_secret_is_refused() -> None:
    msgs, pk = stream(7)
    src = NetSource(url(), secret="s3cret", idle_s=30.0)
    assert receive(src, sender(msgs, secret=b"guess", session=7)) is None  # ends after idle_s
    assert src.counts["dropped_auth"] == 1 and src.counts.get("senders", 0) == 0


def test_udp_spoofed_datagrams_are_counted_drops() -> None:
    """Another address sends a HELLO, a far watermark and a forged END while
    the sender streams: all dropped, the sender's events all arrive."""
    msgs, pk = stream(7)
    spoof = _far_tick(9) + [encode_end(9, 2, zlib.crc32(msgs[0][HEADER:]), 1 << 61), encode_end(7, 500, 0, 5)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

    def datagrams(parts: list[list[bytes]], pause_s: float, after_s: float = 0.0) -> Peer:
        async def peer(_: int) -> None:  # one socket: one address
            await trio.sleep(after_s)
            with trio.socket.socket(trio.socket.AF_INET, trio.socket.SOCK_DGRAM) as u:
                for part in parts:
                    for m in part:
                        await u.sendto(m, ("127.0.0.1", port))
                        await trio.sleep(0.001)
                    await trio.sleep(pause_s)
        return peer

    src = NetSource(f"udp://127.0.0.1:{port}")
    same(receive(src, datagrams([msgs[:3], msgs[3:]], pause_s=1.0), datagrams([spoof], 0.0, after_s=0.5)), pk)
    assert src.counts["dropped_other_sender"] == len(spoof) and src.counts["finished"] == 1


def _unsent_or_unread(port: int) -> int | None:
    """Bytes still queued (sent, not yet read) on the loopback TCP connections
    of ``port`` (Linux ``/proc/net/tcp``); None where that is not readable."""
    try:
        with open("/proc/net/tcp") as f:
            lines = f.read().splitlines()[1:]
    except OSError:
        return None
    queued = 0
    for line in lines:
        f = line.split()
        ports = {int(f[1].rsplit(":", 1)[1], 16), int(f[2].rsplit(":", 1)[1], 16)}
        if port in ports and f[3] == "01":  # ESTABLISHED
            tx, rx = f[4].split(":")
            queued += int(tx, 16) + int(rx, 16)
    return queued


def _receiver(address: str, out) -> tuple[subprocess.Popen, socket.socket]:
    """``tectum run ADDRESS --sink OUT`` and a connection to it."""
    proc = subprocess.Popen([sys.executable, "-m", "tectum", "run", address, "--sink", str(out), "-q"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    port = int(address.rsplit(":", 1)[1])
    deadline = time.monotonic() + 60
    while True:
        try:
            return proc, socket.create_connection(("127.0.0.1", port), timeout=5)
        except OSError:
            assert time.monotonic() < deadline and proc.poll() is None, "the receiver did not listen"
            time.sleep(0.05)


def test_ctrl_c_keeps_what_was_received(tmp_path) -> None:
    """SIGINT to ``tectum run tcp://... --sink rx.npz`` while a sender is
    connected: the file holds every event received, the exit status is 130.

    A first, complete run compiles the receiver's kernels (on an empty numba
    cache they took longer than the wait below: 201 of 3998 events had reached
    the file), and the signal goes once the receiver has read every byte."""
    msgs, pk = stream(7)
    out = tmp_path / "rx.npz"
    address = url()
    proc, c = _receiver(address, out)
    with c:
        c.sendall(b"".join(frame(m) for m in msgs))
    proc.communicate(timeout=120)  # its pipes read to the end and closed
    assert proc.returncode == 0 and len(np.load(out)["t"]) == len(pk)
    out.unlink()
    address = url()
    proc, c = _receiver(address, out)
    with c:
        c.sendall(b"".join(frame(m) for m in msgs[:-1]))  # everything but END: the run would go on
        deadline = time.monotonic() + 60
        while (_unsent_or_unread(int(address.rsplit(":", 1)[1])) or 0) > 0 and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(2.0)  # from the socket to the sink (a few kB)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err.decode()
    assert b"interrupted" in err
    got = np.load(out)
    assert len(got["t"]) == len(pk) and np.array_equal(got["t"], pk.t) and np.array_equal(got["x"], pk.x)


def test_the_sink_proves_the_secret_from_the_environment(monkeypatch) -> None:
    """The real sender (tcp:// sink) with TECTUM_NET_SECRET, against a
    receiver holding the same secret: every event arrives."""
    from tectum.sinks.net.sink import NetSink
    from tectum.testing import ListSink, ListSource

    monkeypatch.setenv("TECTUM_NET_SECRET", "s3cret")
    _, pk = stream(7)
    src = NetSource(url())
    rx = tectum.Pipeline()
    got = ListSink()
    rx.sink(got, rx.source(src))
    th = tectum.ThreadedPipeline(rx, watch=[]).start()
    assert src.ready.wait(60)
    tx = tectum.Pipeline()
    tx.sink(NetSink(f"tcp://127.0.0.1:{src.port}"), tx.source(ListSource([pk])))
    tectum.run(tx)
    th.join(60)
    same(got.events(), pk)
    assert src.counts["finished"] == 1 and src.counts.get("dropped_auth", 0) == 0
