"""``tcp://HOST:PORT`` / ``udp://HOST:PORT`` sinks (framing in
:mod:`tectum.sources.net._wire`).

TCP connects when the pipeline opens (retrying for ``connect_s`` s, so the
receiver may start a moment later), sends every event losslessly with
back-pressure, reconnects and resends the current message if the
connection drops, and sends END when the run ends. With ``secret`` (or the
``TECTUM_NET_SECRET`` environment variable) it answers the receiver's
challenge on each connection (:mod:`tectum.sources.net._auth`). UDP sends datagrams of
at most ``datagram`` bytes (under the MTU), a HELLO every ``hello_every``
datagrams so a late receiver can join, and can pace itself to
``rate_mev_s``; what the network drops the receiver counts.
"""

from __future__ import annotations

import random
import socket
import time
from zlib import crc32

import numpy as np
import trio

from tectum import EventPacket, Kind, Packet, SamplePacket, Sink
from tectum.sources.net._addr import parse
from tectum.sources.net._auth import auth, nonce_of, secret_of
from tectum.sources.net._samples import FRAG, SAMPLES, encode_samples, fragments, sample_pieces, schema_of
from tectum.sources.net._samples import row_bytes as sample_row_bytes
from tectum.sources.net._wire import HEADER, _header, chunks, encode_end, encode_events, encode_hello, row_bytes

__all__ = ["NetSink"]


class NetSink(Sink):
    """Events to the network (see the module docstring).

    Parameters (units): ``connect_s`` seconds to keep trying to connect
    (TCP); ``datagram`` bytes per UDP datagram (576..65000); ``frame_events``
    events per TCP frame; ``rate_mev_s`` UDP pacing in million events/s (0:
    as fast as possible); ``hello_every`` datagrams between UDP HELLOs;
    ``secret`` the receiver's shared secret (TCP).
    """

    name = "net"
    schemes = ("tcp", "udp")
    consumes = (Kind.EVENTS, Kind.IMU, Kind.FRAMES, Kind.POSES, Kind.TRIGGERS)

    def __init__(self, url: str, connect_s: float = 5.0, datagram: int = 1400, frame_events: int = 65536,
                 rate_mev_s: float = 0.0, hello_every: int = 64, secret: str = "") -> None:
        self.scheme, self.host, self.port = parse(url)
        self.secret = secret_of(secret)
        if self.secret and self.scheme == "udp":
            raise ValueError(f"{url!r}: a secret needs tcp:// (UDP datagrams cannot be bound to a handshake)")
        if not 576 <= datagram <= 65000 or frame_events < 1 or rate_mev_s < 0 or hello_every < 1:
            raise ValueError("need 576 <= datagram <= 65000, frame_events >= 1, rate_mev_s >= 0, hello_every >= 1")
        self.connect_s, self.datagram, self.frame_events = connect_s, datagram, frame_events
        self.rate, self.hello_every = rate_mev_s * 1e6, hello_every
        self.session = random.getrandbits(32)
        self.seq = 0
        self.sent_events = self.sent_messages = self.reconnects = self.refused = self.sent_samples = 0
        self.max_sample_bytes = 1 << 22  # TCP: samples per message up to 4 MiB
        self._sock: socket.socket | None = None
        self._stream: trio.SocketStream | None = None
        self._tsock: trio.socket.SocketType | None = None
        self._hello: bytes | None = None
        self._schema = 0
        self._names: list[str] = []
        self._cols: list[tuple[str, np.dtype]] = []
        self._last_end: int | None = None
        self._t0 = 0.0

    # -- connection ---------------------------------------------------------
    def _connect_blocking(self) -> socket.socket:
        deadline = time.monotonic() + self.connect_s
        while True:
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.settimeout(max(0.05, min(1.0, deadline - time.monotonic())))
            try:
                s.connect((self.host, self.port))
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                if self.secret:
                    self._answer(s, deadline)
                return s
            except OSError as e:
                s.close()
                if time.monotonic() >= deadline:
                    raise ConnectionError(f"cannot connect to tcp://{self.host}:{self.port} "
                                          f"within {self.connect_s} s: {e}") from None
                time.sleep(0.02)

    def _answer(self, s: socket.socket, deadline: float) -> None:
        """Read the receiver's challenge and prove the secret."""
        s.settimeout(max(1.0, deadline - time.monotonic()))
        head = b""
        while len(head) < 4 + HEADER + 16:
            got = s.recv(4 + HEADER + 16 - len(head))
            if not got:
                raise ConnectionError(f"tcp://{self.host}:{self.port} closed before its challenge")
            head += got
        nonce = nonce_of(head[4:])
        if nonce is None:
            raise ConnectionError(f"tcp://{self.host}:{self.port} sent no challenge (has it a secret?)")
        s.sendall(_framed(auth(self.secret, nonce, self.session)))
        s.settimeout(None)

    def open(self) -> None:
        if self.scheme == "tcp":
            self._sock = self._connect_blocking()
        else:
            self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._sock.connect((self.host, self.port))
        self._tsock = trio.socket.from_stdlib_socket(self._sock)
        if self.scheme == "tcp":
            self._stream = trio.SocketStream(self._tsock)
        self._t0 = time.perf_counter()

    async def _reconnect(self) -> None:
        deadline = trio.current_time() + self.connect_s
        while True:
            try:
                s = await trio.to_thread.run_sync(self._connect_blocking)
                break
            except ConnectionError:
                if trio.current_time() >= deadline:
                    raise
        self._sock = s
        self._tsock = trio.socket.from_stdlib_socket(s)
        self._stream = trio.SocketStream(self._tsock)
        self.reconnects += 1
        assert self._hello is not None
        await self._stream.send_all(_framed(self._hello))

    # -- sending ------------------------------------------------------------
    def _next_seq(self) -> int:
        s = self.seq
        self.seq += 1
        return s

    async def _send(self, msg: bytes) -> None:
        if self.scheme == "tcp":
            assert self._stream is not None
            try:
                await self._stream.send_all(_framed(msg))
            except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                await self._reconnect()
                await self._stream.send_all(_framed(msg))
        else:
            assert self._tsock is not None
            if self.sent_messages % self.hello_every == 0 and self._hello is not None and msg is not self._hello:
                await self._udp(self._hello_again())
            await self._udp(msg)
        self.sent_messages += 1

    def _hello_again(self) -> bytes:
        """A repeated HELLO for late joiners. It takes no sequence number of
        its own (that would reorder it before the message about to go, whose
        number is already taken): it carries the number before that one."""
        return encode_hello(self.session, (self.seq - 2) & 0xFFFFFFFF, self._sensor, self._cols)

    async def _udp(self, msg: bytes) -> None:
        try:
            await self._tsock.send(msg)  # type: ignore[union-attr]
        except ConnectionRefusedError:  # nobody listens (yet): the datagram is lost
            self.refused += 1

    async def awrite(self, packet: Packet) -> None:
        if isinstance(packet, SamplePacket):
            await self._write_samples(packet)
            return
        assert isinstance(packet, EventPacket)
        if self._hello is None:
            self._sensor = packet.sensor
            self._names = list(packet.columns)
            self._cols = [(k, packet.columns[k].dtype) for k in self._names]
            for k in self._names:
                a = packet.columns[k]
                if a.ndim != 1 or a.dtype.kind not in "biuf" or a.dtype.itemsize > 8:
                    raise ValueError(f"column {k!r} ({a.dtype}, {a.ndim}-D) cannot go over the network")
            self._hello = encode_hello(self.session, self._next_seq(), self._sensor, self._cols)
            self._schema = crc32(self._hello[HEADER:])
            await self._send(self._hello)
        if self.scheme == "udp":
            per = max(1, (self.datagram - HEADER) // row_bytes(self._cols))
        else:
            per = self.frame_events
        for piece, t0, t1 in chunks(packet, per):
            await self._send(encode_events(self.session, self._next_seq(), self._schema, piece, t0, t1,
                                           self._names))
            self.sent_events += len(piece)
            if self.rate and self.scheme == "udp":
                ahead = self.sent_events / self.rate - (time.perf_counter() - self._t0)
                if ahead > 0:
                    await trio.sleep(ahead)
        self._last_end = packet.t_end

    async def _write_samples(self, packet: SamplePacket) -> None:
        """IMU, frames, poses, triggers: self-describing SAMPLES messages;
        over UDP as many samples as fit a datagram, and a message still too
        big (a frame) in FRAG pieces."""
        if not len(packet) and self.scheme == "udp":
            return  # ticks do not travel over UDP
        schema = schema_of(packet)
        desc = len(packet.data) * 48 + 2  # upper bound of the description's size
        budget = self.datagram if self.scheme == "udp" else self.max_sample_bytes
        per = max(1, (budget - HEADER - desc) // sample_row_bytes(packet))
        for piece, t0, t1 in sample_pieces(packet, per):
            seq = self._next_seq()
            t_base = int(piece.t[0]) if len(piece) else t0
            msg = encode_samples(_header(SAMPLES, self.session, seq, schema, t0, t1, t_base, len(piece)), piece,
                                 t_base)
            if self.scheme == "udp" and len(msg) > self.datagram:
                for i, count, part in fragments(msg, self.datagram - HEADER):
                    await self._udp(_header(FRAG, self.session, seq, crc32(part), i, count, len(msg), len(part))
                                    + part)
                    self.sent_messages += 1
            else:
                await self._send(msg)
            self.sent_samples += len(piece)

    def close(self) -> None:
        if self._sock is None:
            return
        try:
            if self._hello is not None or self.sent_samples:
                end = encode_end(self.session, self._next_seq(), self._schema, self._last_end or 0)
                self._sock.settimeout(5.0)
                if self.scheme == "tcp":
                    self._sock.sendall(_framed(end))
                    self._sock.shutdown(socket.SHUT_WR)
                    self._drain()
                else:
                    for _ in range(3):  # END may be lost: send it thrice (duplicates are dropped)
                        try:
                            self._sock.send(end)
                        except ConnectionRefusedError:
                            self.refused += 1
        finally:
            self._sock.close()
            self._sock = None

    def _drain(self) -> None:
        """Wait (bounded) for the receiver to close: it has read everything."""
        assert self._sock is not None
        deadline = time.monotonic() + 5.0
        try:
            while time.monotonic() < deadline:
                if not self._sock.recv(4096):
                    return
        except OSError:
            return

    def abort(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _framed(msg: bytes) -> bytes:
    return len(msg).to_bytes(4, "little") + msg
