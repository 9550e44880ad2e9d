"""``tcp://HOST:PORT`` and ``udp://HOST:PORT`` sources: receive the event
(and IMU, frame, pose, trigger) stream a tectum network sink sends (framing in :mod:`._wire`).

TCP: listens, accepts the sender, and ends when the sender closes after its
END message. If a connection drops without END the source waits up to
``reconnect_s`` s for the sender to come back and goes on (sequence numbers
count anything lost in between). UDP: binds and receives datagrams; ends on
the sender's END or after ``idle_s`` s of silence (0: never). Malformed or
hostile input is rejected and counted (:attr:`NetSource.counts`), never
fatal; memory is bounded by ``max_message`` bytes.
"""

from __future__ import annotations

import math
import threading
from collections.abc import AsyncIterator

import trio

from tectum import Kind, Packet, Source

from ._addr import parse
from ._wire import Receiver

__all__ = ["NetSource"]


class NetSource(Source):
    """Events from the network (see the module docstring).

    Parameters (units): ``idle_s`` seconds of silence that end the stream
    (0: wait forever); ``reconnect_s`` seconds a TCP source waits for a
    dropped sender to reconnect; ``max_message`` largest frame in bytes.
    ``port`` 0 picks a free port (read :attr:`port` once :attr:`ready`).
    """

    name = "net"
    schemes = ("tcp", "udp")
    produces = (Kind.EVENTS, Kind.IMU, Kind.FRAMES, Kind.POSES, Kind.TRIGGERS)

    def __init__(self, url: str, idle_s: float = 0.0, reconnect_s: float = 2.0, max_message: int = 1 << 23,
                 rcvbuf: int = 1 << 22) -> None:
        self.scheme, self.host, self.port = parse(url)
        if idle_s < 0 or reconnect_s < 0 or not 1024 <= max_message <= 1 << 30:
            raise ValueError("idle_s, reconnect_s must be >= 0; max_message within 1 KiB .. 1 GiB")
        self.idle_s, self.reconnect_s, self.max_message, self.rcvbuf = idle_s, reconnect_s, max_message, rcvbuf
        self.receiver = Receiver(max_events=max_message // 9 + 1, max_message=max_message)
        self.ready = threading.Event()
        self.dropped_connections = 0

    @property
    def counts(self) -> dict[str, int]:  # type: ignore[override]  # read-only: derived from the receiver's counters
        """Integer counters (the run's stats show them): accepted, events,
        lost, late, sessions, rejected_total, ``rejected_<reason>`` and
        dropped_connections."""
        c = self.receiver.counts()
        out = {k: v for k, v in c.items() if isinstance(v, int)}
        out.update({f"rejected_{k}": v for k, v in self.receiver.rejected.items()})
        out["dropped_connections"] = self.dropped_connections
        return out

    async def apackets(self) -> AsyncIterator[Packet]:
        gen = self._tcp() if self.scheme == "tcp" else self._udp()
        async for pkt in gen:
            yield pkt
        for pkt in self.receiver.flush(self.receiver.end_t):
            yield pkt

    def _idle(self) -> float:
        return self.idle_s if self.idle_s > 0 else math.inf

    # -- UDP ----------------------------------------------------------------
    async def _udp(self) -> AsyncIterator[Packet]:
        sock = trio.socket.socket(trio.socket.AF_INET, trio.socket.SOCK_DGRAM)
        try:
            sock.setsockopt(trio.socket.SOL_SOCKET, trio.socket.SO_RCVBUF, self.rcvbuf)
            await sock.bind((self.host, self.port))
            self.port = sock.getsockname()[1]
            self.ready.set()
            while not self.receiver.ended:
                with trio.move_on_after(self._idle()) as scope:
                    data = await sock.recv(65536)
                if scope.cancelled_caught:
                    return
                for pkt in self.receiver.feed(data):
                    yield pkt
        finally:
            sock.close()

    # -- TCP ----------------------------------------------------------------
    async def _tcp(self) -> AsyncIterator[Packet]:
        listeners = await trio.open_tcp_listeners(self.port, host=self.host)
        lst = listeners[0]
        self.port = lst.socket.getsockname()[1]
        self.ready.set()
        try:
            first = True
            while not self.receiver.ended:
                wait = self._idle() if first else self.reconnect_s
                stream: trio.SocketStream | None = None
                with trio.move_on_after(wait):
                    stream = await lst.accept()
                if stream is None:
                    return
                first = False
                async with stream:
                    async for pkt in self._frames(stream):
                        yield pkt
                if not self.receiver.ended:
                    self.dropped_connections += 1
        finally:
            for item in listeners:
                await item.aclose()

    async def _frames(self, stream: trio.SocketStream) -> AsyncIterator[Packet]:
        buf = bytearray()
        need = 4
        while True:
            with trio.move_on_after(self._idle()) as scope:
                try:
                    chunk = await stream.receive_some(1 << 20)
                except (trio.BrokenResourceError, OSError):
                    chunk = b""
            if scope.cancelled_caught or not chunk:
                return
            buf += chunk
            while len(buf) >= need:
                n = int.from_bytes(buf[:4], "little")
                if n > self.max_message or n < 4:
                    self.receiver.rejected["length"] = self.receiver.rejected.get("length", 0) + 1
                    return  # framing is lost: drop this connection
                if len(buf) < 4 + n:
                    need = 4 + n
                    break
                msg = bytes(buf[4:4 + n])
                del buf[:4 + n]
                need = 4
                for pkt in self.receiver.feed(msg):
                    yield pkt
                if self.receiver.ended:
                    return
