"""``tectum bench net``: event streaming on loopback.

* TCP: a file's events sent by the ``tcp://`` sink to a ``tcp://`` source
  in another thread; sustained rate (Mev/s) and a check that nothing was
  lost (received == sent).
* UDP: datagrams of tectum's framing sent at a range of rates; for each,
  the fraction lost and the one-way latency (send to decoded, µs), measured
  with both ends in this process on one clock.
"""

from __future__ import annotations

import socket
import threading
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from tectum import Packet, Sink
from tectum.evaluation.harness import table
from tectum.sources.net._wire import HEADER, Receiver, chunks, encode_end, encode_events, encode_hello, row_bytes

__all__ = ["run"]


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _packets(n_events: int) -> list[Any]:
    from tectum.sources.pattern import PatternSource

    dur = max(100_000, int(n_events / 40))  # the pattern makes ~40 ev/µs... roughly; trimmed below
    pk = list(PatternSource("pattern:", sensor="346x260", duration_us=dur, speed=2000.0, window_us=20_000).packets())
    return pk


def tcp_rate(n_events: int) -> dict[str, Any]:
    import tectum
    from tectum.sinks.net.sink import NetSink
    from tectum.sources.net.source import NetSource
    from tectum.testing import ListSource

    pk = _packets(n_events)
    sent = sum(len(p) for p in pk)
    port = _free_port(socket.SOCK_STREAM)
    src = NetSource(f"tcp://127.0.0.1:{port}")
    rx = tectum.Pipeline()
    got = _Count()
    rx.sink(got, rx.source(src))
    th = tectum.ThreadedPipeline(rx, watch=[]).start()
    src.ready.wait(5)
    tx = tectum.Pipeline()
    tx.sink(NetSink(f"tcp://127.0.0.1:{port}"), tx.source(ListSource(pk)))
    t0 = time.perf_counter()
    tectum.run(tx)
    th.join(30)
    dt = time.perf_counter() - t0
    return {"events": sent, "received": got.events, "lossless": got.events == sent, "seconds": dt,
            "mev_s": sent / dt / 1e6, "lost_messages": src.counts["lost"]}


class _Count(Sink):
    """A sink that counts the events it receives."""

    name = "count"

    def __init__(self) -> None:
        self.events = 0

    def write(self, packet: Packet) -> None:
        self.events += len(packet)


def _receive(rx: socket.socket, rec: Receiver, sent_at: dict[int, float], lat: list[float]) -> None:
    """Feed the datagrams of ``rx`` to ``rec`` until the stream ends or ``rx``
    times out; the latency (s) of each accepted datagram whose send time is in
    ``sent_at`` (by sequence number) goes to ``lat``."""
    while True:
        try:
            data = rx.recv(65536)
        except OSError:
            return
        now = time.perf_counter()
        seq = int.from_bytes(data[8:12], "little")
        before = rec.accepted
        rec.feed(data)
        if rec.accepted > before and seq in sent_at:
            lat.append(now - sent_at[seq])
        if rec.ended:
            return


def udp_curve(rates_mev_s: list[float], n_events: int) -> list[dict[str, Any]]:
    pk = _packets(n_events)
    rows = []
    for rate in rates_mev_s:
        port = _free_port(socket.SOCK_DGRAM)
        rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        rx.bind(("127.0.0.1", port))
        rx.settimeout(0.5)
        sent_at: dict[int, float] = {}
        lat: list[float] = []
        rec = Receiver()
        th = threading.Thread(target=_receive, args=(rx, rec, sent_at, lat))
        th.start()
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        tx.connect(("127.0.0.1", port))
        hello = encode_hello(1, 0, pk[0].sensor, [])
        schema = zlib.crc32(hello[HEADER:])
        tx.send(hello)
        seq, n, t0 = 1, 0, time.perf_counter()
        per = (1400 - HEADER) // row_bytes([])
        for p in pk:
            p = p.without_columns(*p.columns)
            for piece, a, b in chunks(p, per):
                msg = encode_events(1, seq, schema, piece, a, b, [])
                sent_at[seq] = time.perf_counter()
                tx.send(msg)
                seq += 1
                n += len(piece)
                if rate:
                    ahead = n / (rate * 1e6) - (time.perf_counter() - t0)
                    if ahead > 0:
                        time.sleep(ahead)
        for _ in range(3):
            tx.send(encode_end(1, seq, schema, pk[-1].t_end))
        th.join(5)
        rx.close()
        tx.close()
        dt = time.perf_counter() - t0
        la = np.array(lat) * 1e6 if lat else np.array([np.nan])
        rows.append({"paced_mev_s": rate or "max", "sent_mev_s": n / dt / 1e6, "events": n,
                     "received": rec.events, "loss": 1 - rec.events / n, "lost_datagrams": rec.lost,
                     "latency_p50_us": float(np.median(la)), "latency_p99_us": float(np.percentile(la, 99))})
    return rows


def run(out: Path, quick: bool) -> dict[str, Any]:
    n = 1_000_000 if quick else 10_000_000
    tcp = tcp_rate(n)
    print(table([tcp], ["events", "received", "lossless", "mev_s"]))
    rates = [0.5, 2.0, 0.0] if quick else [0.5, 1.0, 2.0, 5.0, 10.0, 0.0]
    udp = udp_curve(rates, n // 2)
    print(table(udp, ["paced_mev_s", "sent_mev_s", "loss", "latency_p50_us", "latency_p99_us"]))
    return {"tcp": tcp, "udp": udp}
