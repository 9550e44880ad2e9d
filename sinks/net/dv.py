"""``dv+tcp://HOST:PORT`` sink: serve the stream as iniVation's AEDAT 4.0
network stream, the way dv-processing's ``dv.io.NetworkWriter`` and DV's TCP
server do; dv-processing's ``dv.io.NetworkReader``, DV's GUI and tectum's
``dv+tcp`` source connect to it as clients (protocol in
:mod:`tectum.sources.net._dv`).

The sink listens when the pipeline opens and, before the first packet, waits
up to ``wait_s`` s for ``wait_clients`` clients (so a recording is not
streamed into the void); clients that connect later get the IOHeader and
the stream from then on (as with DV). Every client gets every packet, with
back-pressure; a client that stops reading for ``send_timeout_s`` s is
dropped (counted). DV's stream has no end marker: at the end the sink keeps
the connections open ``linger_s`` s more, then closes them (dv-processing's
``NetworkReader`` discards what it has received but not yet handed out
when the connection closes, so closing at once loses the tail of the
stream).
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass
from typing import Literal

import trio

from tectum import EventPacket, FramePacket, ImuPacket, Kind, Packet, Sink
from tectum.errors import TectumError
from tectum.sources.files import aedat4_codec as codec
from tectum.sources.net._dv import StreamDecl, io_header, packet_bytes
from tectum.sources.net.dv import parse_dv_url

__all__ = ["DvNetSink"]

_KIND_OF = {EventPacket: "events", ImuPacket: "imu", FramePacket: "frames"}


@dataclass
class _Client:
    stream: trio.SocketStream
    new: bool = True  # the IOHeader is still to be sent


class DvNetSink(Sink):
    """Serve events (and IMU samples, frames) to DV clients.

    Parameters (units): ``stream`` the one kind served (``events``,
    ``imu`` or ``frames``: DV's network stream carries one stream per
    connection, as dv-processing's ``NetworkReader`` reads it; run one sink
    per kind, on its own port); ``compression``
    ``none`` (as dv-processing's writer by default), ``lz4``, ``lz4_high``,
    ``zstd``, ``zstd_high``; ``wait_clients`` clients to wait for before
    sending (0: none), for at most ``wait_s`` s; ``max_clients``;
    ``packet_events`` most events per DV packet; ``send_timeout_s``;
    ``sensor`` ``WxH`` when no event packet will tell it (frames/IMU only);
    ``linger_s`` seconds the connections stay open after the last packet.
    Port 0 picks a free port (read :attr:`port` once :attr:`ready`).
    """

    name = "dv_net"
    schemes = ("dv+tcp",)
    consumes = (Kind.EVENTS, Kind.IMU, Kind.FRAMES)

    def __init__(self, url: str, stream: Literal["events", "imu", "frames"] = "events", compression: str = "none",
                 wait_clients: int = 1, wait_s: float = 30.0, max_clients: int = 8, packet_events: int = 1 << 16,
                 send_timeout_s: float = 10.0, sensor: str = "", linger_s: float = 1.0) -> None:
        self.host, self.port = parse_dv_url(url)
        if stream not in ("events", "imu", "frames"):
            raise ValueError(f"stream must be events, imu or frames; got {stream!r}")
        if (wait_clients < 0 or wait_s < 0 or not 0 <= linger_s <= 60 or not 1 <= max_clients <= 256
                or packet_events < 1 or send_timeout_s <= 0):
            raise ValueError("need wait_clients >= 0, wait_s >= 0, 1 <= max_clients <= 256, packet_events >= 1, "
                             "send_timeout_s > 0, 0 <= linger_s <= 60")
        self.stream = stream
        self.comp = codec.compression_code(compression)
        self.wait_clients, self.wait_s, self.max_clients = wait_clients, wait_s, max_clients
        self.packet_events, self.send_timeout_s, self.linger_s = packet_events, send_timeout_s, linger_s
        self.sensor: tuple[int, int] | None = None
        if sensor:
            w, _, h = sensor.lower().partition("x")
            self.sensor = (int(w), int(h))
        self.ready = threading.Event()
        self.counts: dict[str, int] = {"clients": 0, "dropped_clients": 0, "refused_clients": 0, "packets": 0,
                                       "bytes": 0, "ignored": 0}
        self._lsock: socket.socket | None = None
        self._clients: list[_Client] = []
        self._header: bytes | None = None

    # -- listening ------------------------------------------------------------
    def open(self) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((self.host, self.port))
            s.listen(self.max_clients)
        except OSError as e:
            s.close()
            raise OSError(f"dv+tcp sink cannot listen on {self.host}:{self.port}: {e}") from None
        s.setblocking(False)
        self._lsock = s
        self.port = s.getsockname()[1]
        self.ready.set()

    def _accept(self) -> None:
        """Take every connection waiting in the backlog (never blocks)."""
        assert self._lsock is not None
        while True:
            try:
                conn, _ = self._lsock.accept()
            except (BlockingIOError, InterruptedError):
                return
            if len(self._clients) >= self.max_clients:
                conn.close()
                self.counts["refused_clients"] += 1
                continue
            conn.setblocking(False)
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._clients.append(_Client(trio.SocketStream(trio.socket.from_stdlib_socket(conn))))
            self.counts["clients"] += 1

    async def _wait_for_clients(self) -> None:
        deadline = time.monotonic() + self.wait_s
        while True:
            self._accept()
            if len(self._clients) >= self.wait_clients:
                return
            if time.monotonic() >= deadline:
                raise TectumError(f"dv+tcp://{self.host}:{self.port}: {len(self._clients)} of {self.wait_clients} "
                                  f"DV client(s) connected within {self.wait_s} s")
            await trio.sleep(0.01)

    # -- sending --------------------------------------------------------------
    async def _start(self) -> None:
        decl = StreamDecl(0, self.stream, self.sensor if self.stream != "imu" else None)
        await self._wait_for_clients()
        self._header = io_header([decl], self.comp)

    async def _send(self, data: bytes) -> None:
        self._accept()
        for c in list(self._clients):
            ok = False
            with trio.move_on_after(self.send_timeout_s):
                try:
                    if c.new:
                        assert self._header is not None
                        await c.stream.send_all(self._header)
                        c.new = False
                    await c.stream.send_all(data)
                    ok = True
                except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                    pass
            if not ok:
                self.counts["dropped_clients"] += 1
                self._clients.remove(c)
                await _close_quietly(c)
        self.counts["bytes"] += len(data)

    async def awrite(self, packet: Packet) -> None:
        if isinstance(packet, EventPacket) and self.sensor is None:
            self.sensor = packet.sensor  # also for frames: DAVIS frames have the sensor's size
        if isinstance(packet, FramePacket) and self.sensor is None and len(packet):
            self.sensor = (int(packet.images.shape[2]), int(packet.images.shape[1]))
        if _KIND_OF.get(type(packet)) != self.stream:
            self.counts["ignored"] += 1
            return
        if self._header is None:
            if self.stream != "imu" and self.sensor is None:
                return  # only empty frame packets come before the size is known: nothing to send
            await self._start()
        await self._put(packet)

    async def _put(self, packet: Packet) -> None:
        if not len(packet):
            return
        if isinstance(packet, EventPacket):
            parts = [codec.encode_events(b) for b in packet.batches(self.packet_events)]
        elif isinstance(packet, ImuPacket):
            parts = [codec.encode_imu(packet)]
        else:
            assert isinstance(packet, FramePacket)
            parts = codec.encode_frames(packet)
        data = b"".join(packet_bytes(0, codec.compress(b, self.comp)) for b in parts)
        self.counts["packets"] += len(parts)
        await self._send(data)

    # -- ending ---------------------------------------------------------------
    async def aclose(self) -> None:
        try:
            if self._header is None and self._lsock is not None and (self.sensor is not None or self.stream == "imu"):
                await self._start()
            if self._clients:
                await trio.sleep(self.linger_s)
            for c in self._clients:  # a half close: the client reads to the end, then sees EOF
                with trio.move_on_after(self.send_timeout_s):
                    try:
                        if c.new and self._header is not None:
                            await c.stream.send_all(self._header)
                        await c.stream.send_eof()
                    except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
                        pass
        finally:
            await self.aabort()

    async def aabort(self) -> None:
        clients, self._clients = self._clients, []
        for c in clients:
            await _close_quietly(c)
        self.close()

    def close(self) -> None:
        """Stop listening (the async :meth:`aclose` also ends the clients'
        streams; this is for use outside a pipeline)."""
        if self._lsock is not None:
            self._lsock.close()
            self._lsock = None


async def _close_quietly(c: _Client) -> None:
    try:
        await c.stream.aclose()
    except (trio.BrokenResourceError, trio.ClosedResourceError, OSError):
        pass
