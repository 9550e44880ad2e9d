"""The base of the file sinks: stream into a temporary file beside the target,
``os.replace`` it into place on :meth:`close`, delete it on :meth:`abort`."""

from __future__ import annotations

import os
import tempfile
from typing import IO, Any, ClassVar

from tectum import EventPacket, Kind, Packet, Sink

__all__ = ["FileSink"]


class FileSink(Sink):
    """Subclasses implement :meth:`_begin` (first packet: write the header),
    :meth:`_events` and optionally :meth:`_end` (before the commit)."""

    format: ClassVar[str] = ""
    consumes: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS,)

    def __init__(self, path: str) -> None:
        self.path = os.fspath(path)
        self._tmp: str | None = None
        self.f: IO[bytes] | None = None
        self.sensor: tuple[int, int] | None = None
        self.count = 0

    def open(self) -> None:
        parent = os.path.dirname(os.path.abspath(self.path))
        if not os.path.isdir(parent):
            raise FileNotFoundError(f"folder {parent!r} does not exist")
        fd, self._tmp = tempfile.mkstemp(prefix=".tectum-", suffix=".part", dir=parent)
        self.f = os.fdopen(fd, "w+b")

    def write(self, packet: Packet) -> None:
        if self.f is None:
            self.open()
        if not isinstance(packet, EventPacket):
            self._other(packet)
            return
        if self.sensor is None:
            self.sensor = packet.sensor
            self._begin(packet)
        elif packet.sensor != self.sensor:
            raise ValueError(f"sensor size changed from {self.sensor} to {packet.sensor}")
        if len(packet):
            self._events(packet)
            self.count += len(packet)

    def _other(self, packet: Packet) -> None:
        """Packets of other kinds: ignored unless a format stores them."""

    def _begin(self, packet: EventPacket) -> None:
        raise NotImplementedError

    def _events(self, packet: EventPacket) -> None:
        raise NotImplementedError

    def _end(self) -> None:
        """Finish the file (footer, patched header) before it is committed."""

    def close(self) -> None:
        if self.f is None:
            self.open()
        assert self.f is not None
        try:
            if self.sensor is None:
                self._empty()
            self._end()
            self.f.flush()
            os.fsync(self.f.fileno())
            self.f.close()
            assert self._tmp is not None
            os.replace(self._tmp, self.path)
            self._tmp = None
        finally:
            self._cleanup()

    def _empty(self) -> None:
        """Nothing was written: the header of an empty file."""
        raise ValueError(f"{self.format}: no events were written and the sensor size is unknown")

    def abort(self) -> None:
        self._cleanup()

    def _cleanup(self) -> None:
        if self.f is not None:
            try:
                self.f.close()
            except OSError:
                pass
            self.f = None
        discard(self._tmp)
        self._tmp = None


def discard(path: str | None) -> None:
    """Remove a partial output file, if there is one (after an abort)."""
    if path is not None:
        try:
            os.unlink(path)
        except OSError:
            pass


def header_date() -> str:
    import time

    return time.strftime("%Y-%m-%d %H:%M:%S")


def write_all(sink: Any, packets: Any) -> None:
    """Open ``sink``, write every packet, close (abort on error)."""
    sink.open()
    try:
        for p in packets:
            sink.write(p)
    except BaseException:
        sink.abort()
        raise
    sink.close()
