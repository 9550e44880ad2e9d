"""Two tectum processes chained over TCP, and a UDP stream on loopback."""

from __future__ import annotations

import socket
import subprocess
import sys

import numpy as np

import tectum
from tectum.sinks.net.sink import NetSink
from tectum.sources.net.source import NetSource
from tectum.testing import ListSink


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_receiver(url: str, **kw) -> tuple[NetSource, ListSink, tectum.ThreadedPipeline]:
    """A network source feeding a ListSink, running in a background thread."""
    src = NetSource(url, **kw)
    rx = tectum.Pipeline()
    got = ListSink()
    rx.sink(got, rx.source(src))
    th = tectum.ThreadedPipeline(rx, watch=[]).start()
    assert src.ready.wait(60)
    return src, got, th


def tectum_cli(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tectum", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def test_two_processes_over_tcp_give_the_same_file(tmp_path) -> None:
    sent, rx = tmp_path / "tx.npz", tmp_path / "rx.npz"
    p = tectum.Pipeline()
    p.sink(str(sent), p.source("pattern:", sensor="64x48", duration_us=200_000, noise_hz=20.0))
    tectum.run(p)
    port = free_port()
    recv = tectum_cli("run", f"tcp://127.0.0.1:{port}", "--sink", str(rx))
    send = tectum_cli("run", str(sent), "--sink", f"tcp://127.0.0.1:{port}")  # may start first: it retries
    _, err = send.communicate(timeout=60)  # read to the end (a full pipe would stall the child), closed
    assert send.returncode == 0, err
    _, err = recv.communicate(timeout=60)
    assert recv.returncode == 0, err
    a, b = np.load(sent), np.load(rx)
    assert sorted(a.files) == sorted(b.files)
    for k in a.files:
        assert np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f"), k


def _udp_run(rate: float) -> tuple[tectum.EventPacket, ListSink, NetSource, NetSink]:
    port = free_port(socket.SOCK_DGRAM)
    src, got, th = start_receiver(f"udp://127.0.0.1:{port}", idle_s=20.0)  # ends on the END message; idle only as a safety net
    tx = tectum.Pipeline()
    sink = NetSink(f"udp://127.0.0.1:{port}", rate_mev_s=rate)
    s = tx.source("pattern:", sensor="64x48", duration_us=100_000)
    truth = ListSink()
    tx.sink(sink, s)
    tx.sink(truth, s)
    tectum.run(tx)
    th.join(40)
    return truth.events(), got, src, sink


def test_udp_stream_arrives_whole_at_a_modest_rate_with_extra_columns() -> None:
    truth, got, src, sink = _udp_run(rate=0.5)
    ev = got.events()
    c = src.counts
    assert c["lost"] == 0 and c["rejected_total"] == 0
    assert np.array_equal(ev.t, truth.t) and np.array_equal(ev.x, truth.x)
    assert np.array_equal(ev["vx"], truth["vx"], equal_nan=True)
    assert sink.sent_messages > 20  # many datagrams, each under the MTU


def test_udp_loss_is_counted_not_fatal() -> None:
    """Datagrams dropped between sink and source (a lossy link, emulated by
    a relay that drops every 5th datagram) are counted by the receiver."""
    port_rx, port_relay = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_DGRAM)
    src, got, th = start_receiver(f"udp://127.0.0.1:{port_rx}", idle_s=20.0)  # ends on the END message; idle only as a safety net
    import threading

    relay = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    relay.bind(("127.0.0.1", port_relay))
    relay.settimeout(0.5)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dropped = []
    stop = threading.Event()

    def forward() -> None:
        i = 0
        while not stop.is_set():  # runs until told: the sender may be slow to start
            try:
                d = relay.recv(65536)
            except TimeoutError:
                continue
            except OSError:
                return
            if d[3] == 1 and i % 5 == 4:  # drop some EVENTS datagrams
                dropped.append(i)
            else:
                out.sendto(d, ("127.0.0.1", port_rx))
            i += 1

    t = threading.Thread(target=forward)
    t.start()
    tx = tectum.Pipeline()
    tx.sink(NetSink(f"udp://127.0.0.1:{port_relay}", rate_mev_s=0.5),
            tx.source("pattern:", sensor="64x48", duration_us=50_000))
    tectum.run(tx)
    th.join(40)
    stop.set()
    t.join(5)
    relay.close()
    out.close()
    assert dropped and src.counts["lost"] == len(dropped)
    ev = got.events()
    assert len(ev) > 0 and np.all(np.diff(ev.t) >= 0)
