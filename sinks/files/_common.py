"""The base of the file sinks: stream into a temporary file beside the target,
``os.replace`` it into place on :meth:`close`, delete it on :meth:`abort`."""

from __future__ import annotations

import os
import secrets
from typing import IO, Any, ClassVar

from tectum import EventPacket, Kind, Packet, Sink

__all__ = ["FileSink", "temp_beside", "discard", "write_all", "count_unwritten"]


class FileSink(Sink):
    """Subclasses implement :meth:`_begin` (first packet: write the header),
    :meth:`_events` and optionally :meth:`_end` (before the commit)."""

    format: ClassVar[str] = ""
    #: The format's name in messages (``EVT 3.0``), and what it holds when
    #: not just the kinds it consumes (see :mod:`tectum.cli._unwritten`).
    title: ClassVar[str] = ""
    holds: ClassVar[str] = ""
    consumes: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS,)
    #: Whether the file records the sensor size (a header's width and height)
    stores_sensor: ClassVar[bool] = False

    def __init__(self, path: str) -> None:
        self.path = os.fspath(path)
        self._tmp: str | None = None
        self.f: IO[bytes] | None = None
        self.sensor: tuple[int, int] | None = None
        self.count = 0

    def open(self) -> None:
        fd, self._tmp = temp_beside(self.path)
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

    @staticmethod
    def _origin(packet: EventPacket, limit: int, name: str) -> int:
        """The time (µs) a format that stores no time origin counts from:
        0, or the first packet's start when its first event comes at
        ``limit`` µs or later (else the file would open with that long a run
        of overflow bytes or records). A time before it is a ValueError."""
        first = int(packet.t[0]) if len(packet) else packet.t_start
        t0 = packet.t_start if first >= limit else 0
        if first < t0 or first < 0:
            raise ValueError(f"time {first} µs is before the {name} origin {t0} µs")
        return t0

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


def count_unwritten(counts: dict[str, int], packet: Packet) -> None:
    """Count ``packet``'s events or samples in ``counts`` by kind: a sink's
    ``not_written`` (what reached it and was not stored), which ``tectum
    run`` reports."""
    if len(packet):
        counts[str(packet.kind)] = counts.get(str(packet.kind), 0) + len(packet)


def temp_beside(path: str, suffix: str = ".part") -> tuple[int, str]:
    """A new empty file in the folder of ``path``, to be renamed onto it when
    complete: ``(fd open for reading and writing, its name)``. Created with
    mode 0o666 less the umask, as the target itself would be (mkstemp's
    0o600 would make every output private). The folder must exist."""
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise FileNotFoundError(f"folder {parent!r} does not exist")
    flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    while True:
        name = os.path.join(parent, f".tectum-{secrets.token_hex(6)}{suffix}")
        try:
            return os.open(name, flags, 0o666), name
        except FileExistsError:  # 2^48 names: another writer drew the same one
            continue


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
