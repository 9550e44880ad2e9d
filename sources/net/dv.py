"""``dv+tcp://HOST:PORT`` — read the AEDAT 4.0 network stream of a DV
server (dv-processing's ``dv.io.NetworkWriter``, DV's TCP server module, or
tectum's own ``dv+tcp`` sink). Protocol in :mod:`._dv`.

The source is the client: it connects (retrying for ``connect_s`` s, so the
server may start a moment later), reads the IOHeader, then packets until
the server closes the connection (or ``idle_s`` s pass without data).
"""

from __future__ import annotations

import math
import time
from collections.abc import AsyncIterator
from urllib.parse import urlsplit

import trio

from tectum import Kind, Packet, Source
from tectum.errors import TectumError

from ._dv import KINDS, DvDecoder, DvParser

__all__ = ["DvNetSource", "parse_dv_url"]


def parse_dv_url(url: str) -> tuple[str, int]:
    """(host, port) of ``dv+tcp://HOST:PORT``."""
    u = urlsplit(url)
    try:
        port = u.port
    except ValueError:
        port = None
    if u.scheme != "dv+tcp" or not u.hostname or port is None:
        raise ValueError(f"{url!r}: expected dv+tcp://HOST:PORT")
    return u.hostname, port


class DvNetSource(Source):
    """Events (and IMU samples, frames, triggers) from a DV network server.

    Parameters (units): ``connect_s`` seconds to keep trying to connect;
    ``idle_s`` seconds without data that end the stream (0: wait until the
    server closes); ``streams`` comma-separated kinds to read (``events``,
    ``imu``, ``frames``, ``triggers``); ``max_packet`` largest packet in
    bytes (a larger one drops the connection, counted).
    """

    name = "dv_net"
    schemes = ("dv+tcp",)
    produces = (Kind.EVENTS, Kind.IMU, Kind.FRAMES, Kind.TRIGGERS)

    def __init__(self, url: str, connect_s: float = 5.0, idle_s: float = 0.0,
                 streams: str = "events,imu,frames,triggers", max_packet: int = 1 << 26) -> None:
        self.host, self.port = parse_dv_url(url)
        kinds = {k.strip() for k in streams.split(",") if k.strip()}
        if not kinds or not kinds <= set(KINDS):
            raise ValueError(f"streams must be among {list(KINDS)}, got {streams!r}")
        if connect_s < 0 or idle_s < 0 or not 1024 <= max_packet <= 1 << 30:
            raise ValueError("connect_s, idle_s must be >= 0; max_packet within 1 KiB .. 1 GiB")
        self.kinds, self.connect_s, self.idle_s, self.max_packet = kinds, connect_s, idle_s, max_packet
        self.decoder: DvDecoder | None = None
        self.counts: dict[str, int] = {"bytes": 0, "connect_attempts": 0, "protocol_errors": 0}
        self.sensor: tuple[int, int] | None = None

    async def _connect(self) -> trio.SocketStream:
        deadline = time.monotonic() + self.connect_s
        while True:
            self.counts["connect_attempts"] += 1
            try:
                return await trio.open_tcp_stream(self.host, self.port)
            except OSError as e:
                if time.monotonic() >= deadline:
                    raise TectumError(f"cannot connect to dv+tcp://{self.host}:{self.port} "
                                      f"within {self.connect_s} s: {e}") from None
                await trio.sleep(0.02)

    async def apackets(self) -> AsyncIterator[Packet]:
        stream = await self._connect()
        parser = DvParser(max_packet=self.max_packet)
        idle = self.idle_s if self.idle_s > 0 else math.inf
        async with stream:
            while True:
                chunk = b""
                with trio.move_on_after(idle):
                    try:
                        chunk = await stream.receive_some(1 << 20)
                    except (trio.BrokenResourceError, OSError):
                        chunk = b""
                if not chunk:
                    break
                self.counts["bytes"] += len(chunk)
                try:
                    got = parser.feed(chunk)
                except ValueError as e:
                    self.counts["protocol_errors"] += 1
                    if parser.streams is None:  # not a DV server at all: say so
                        raise TectumError(f"dv+tcp://{self.host}:{self.port}: {e}") from None
                    break  # framing lost mid-stream: end with what was read
                if parser.streams is not None and self.decoder is None:
                    assert parser.compression is not None
                    self.decoder = DvDecoder(parser.compression, parser.streams, self.kinds)
                    self.sensor = self.decoder.sensor
                for sid, payload in got:
                    assert self.decoder is not None
                    for pkt in self.decoder.decode(sid, payload):
                        yield pkt
                self._sync_counts()
        if self.decoder is not None:
            for pkt in self.decoder.flush():
                yield pkt
            self._sync_counts()

    def _sync_counts(self) -> None:
        if self.decoder is not None:
            self.counts.update(self.decoder.counts)
