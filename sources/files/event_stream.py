"""Event Stream 2.x files (``.es``: sepia, loris, the neuromorphic-systems
``event_stream`` package, faery, command_line_tools), recognised by their
first bytes ``Event Stream``.

Layout and conventions in :mod:`.event_stream_codec`. tectum reads the DVS
and ATIS types:

* DVS events become events (t µs from the file's origin 0, x, y flipped
  from the format's bottom-left origin to tectum's top-left, p ±1).
* ATIS change-detection events become events the same way. ATIS threshold
  crossings (the two halves of each exposure measurement: the time between
  a pixel's first and second crossing encodes its grey level, shorter is
  brighter) are not brightness changes: mixed into the event stream, every
  operator would take them for some. They become their own stream, kind
  ``exposures`` (:class:`ExposurePacket`: t, x, y, ``second``), which
  ``tectum info`` lists, ``--sink x.npz`` keeps, and an operator can ask
  for by kind (faery drops them without a word). Pairing the halves into
  grey levels is left to the consumer: it is the raw measurement, lossless.
* Generic (user bytes), Asynchronous & Modular Display and color events
  (r, g, b, no polarity) have no event-camera equivalent: a clear
  :class:`tectum.FormatError`.

Times never decrease (they are sums of deltas), so the only bad input is a
coordinate outside the header's sensor (raised, or with ``skip_bad`` dropped
and counted) and a file ending inside an event (the same). The format
re-synchronises by itself (*reset* bytes): a bit error garbles the events up
to the next run of resets, and those of them that land outside the sensor
are caught.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from typing import Any

import numpy as np

from tectum import Field, Kind, Packet, SamplePacket, register_kind

from . import event_stream_codec as C
from ._common import EventAssembler, FileSource, SampleTiler

__all__ = ["EventStreamSource", "ExposurePacket", "read_header"]


@register_kind
class ExposurePacket(SamplePacket):
    """ATIS exposure measurements as recorded: one threshold crossing per
    sample at ``t`` (µs) and pixel ``(x, y)`` (top-left origin), ``second``
    False for the first crossing of a measurement and True for the second;
    a pixel's grey level is inversely proportional to the time between
    them."""

    kind = Kind("exposures")
    fields = {
        "x": Field("u2", (), "px", doc="column"),
        "y": Field("u2", (), "px", doc="row, from the top"),
        "second": Field("bool", (), "", doc="the second crossing (exposure end), else the first"),
    }


def read_header(head: bytes, fail: Any) -> tuple[int, tuple[int, int], int]:
    """``(type byte, (width, height), first byte of the events)`` of a DVS or
    ATIS file whose first bytes are ``head``; anything else calls ``fail(message,
    offset)``, which raises."""
    if not head.startswith(C.MAGIC):
        fail("not an Event Stream file (first bytes are not 'Event Stream')", 0)
    if len(head) < 16:
        fail(f"file ends inside the Event Stream header ({len(head)} of 16 bytes)", len(head))
    major, minor, patch, kind = head[12], head[13], head[14], head[15]
    if major != 2:
        fail(f"Event Stream version {major}.{minor}.{patch}: tectum reads version 2.x", 12)
    if kind not in C.TYPES:
        fail(f"unknown Event Stream type byte 0x{kind:02x} (0 generic, 1 dvs, 2 atis, 3 display, 4 color)", 15)
    if kind not in (C.DVS, C.ATIS):
        what = {0: "generic events (user bytes, no pixel or polarity)",
                3: "Asynchronous & Modular Display events (x, y, pyramid stage: a display, not a sensor)",
                4: "color events (x, y, r, g, b: no polarity)"}[kind]
        fail(f"the Event Stream file holds {what}: tectum reads the dvs and atis types", 15)
    if len(head) < C.HEADER_BYTES:
        fail(f"file ends inside the Event Stream header ({len(head)} of {C.HEADER_BYTES} bytes)", len(head))
    w = int.from_bytes(head[16:18], "little")
    h = int.from_bytes(head[18:20], "little")
    if w == 0 or h == 0:
        fail(f"the Event Stream header gives an empty sensor {w}x{h}", 16)
    return kind, (w, h), C.HEADER_BYTES


class EventStreamSource(FileSource):
    """Events from Event Stream 2.x DVS and ATIS files (see the module
    docstring for the mapping; ``sensor=`` checks the header's size)."""

    name = "es"
    format = "event_stream"
    extensions = (".es",)
    produces = (Kind.EVENTS, ExposurePacket.kind)

    def __init__(self, path: str, **kw: Any) -> None:
        super().__init__(path, **kw)
        #: The type in the header: ``"dvs"`` or ``"atis"`` (after reading).
        self.stream_type = ""

    @classmethod
    def sniff(cls, head: bytes) -> bool:
        return head.startswith(C.MAGIC)

    def info(self) -> dict[str, Any]:
        out = super().info()
        out["stream_type"] = self.stream_type
        return out

    def _packets(self) -> Iterator[Packet]:
        f = self._open()
        kind, found, pos = read_header(f.read(C.HEADER_BYTES), self._fail)
        self.stream_type = C.TYPES[kind]
        sensor = self._sensor(found)
        assert sensor is not None
        f.seek(pos)
        state = np.zeros(C.STATE, np.int64)
        asm = EventAssembler(self, sensor)
        exposures = _Exposures(self, sensor)
        atis = kind == C.ATIS
        stopped = False
        while True:
            buf = f.read(self.chunk_bytes)
            if not buf:
                break
            state[7] = pos
            m = len(buf) // 5 + 1
            t, x, y, p = asm.reserve(m)  # decoded straight into the packets' columns
            where = np.empty(m, np.int64)
            k = m if atis else 0  # DVS files have no threshold crossings
            tc = (np.empty(k, np.int64), np.empty(k, np.uint16), np.empty(k, np.uint16), np.empty(k, np.bool_),
                  np.empty(k, np.int64))
            n = C.decode(np.frombuffer(buf, np.uint8), state, atis, sensor[1], t, x, y, p, where, *tc)
            yield from asm.commit(n, pos, functools.partial(_head, where, n), (True, int(state[8]), int(state[9])))
            c = int(state[6])
            yield from exposures.push(tc[0][:c], tc[1][:c], tc[2][:c], tc[3][:c], tc[4][:c], pos)
            pos += len(buf)
            if self.t_end_us is not None and asm.last_t is not None and asm.last_t >= self.t_end_us:
                stopped = True
                break
        if state[0] != 0 and not stopped:
            start = int(state[5])
            if not self.skip_bad:
                self._fail(f"file ends inside an event (truncated: {state[0]} of its 5 bytes)", start)
            self._note_skip(start, pos - 1, 1)
        yield from asm.finish()
        yield from exposures.finish(pos)


def _head(a: np.ndarray, n: int) -> np.ndarray:
    return a[:n]


class _Exposures:
    """ATIS threshold crossings into :class:`ExposurePacket` packets: those
    outside the sensor raised or (``skip_bad``) dropped and counted, those at
    a chunk's last time held back for the next (a time stays in one packet)."""

    def __init__(self, src: FileSource, sensor: tuple[int, int]) -> None:
        self.src = src
        self.sensor = sensor
        self.tiler = SampleTiler(src)
        self.held: tuple[np.ndarray, ...] | None = None

    def push(self, t: np.ndarray, x: np.ndarray, y: np.ndarray, second: np.ndarray, where: np.ndarray, pos: int,
             final: bool = False) -> list[ExposurePacket]:
        """Crossings ``t, x, y, second`` found at byte offsets ``where`` of
        the chunk read from ``pos``: the packet they complete, if any."""
        out = (x >= self.sensor[0]) | (y >= self.sensor[1])
        if out.any():
            bad = np.flatnonzero(out)
            if not self.src.skip_bad:
                i = int(bad[0])
                self.src._fail(f"threshold crossing ({int(x[i])}, {int(y[i])}) lies outside the "
                               f"{self.sensor[0]}x{self.sensor[1]} sensor", int(where[i]))
            self.src._note_skip(int(where[bad[0]]), int(where[bad[-1]]) + 4, int(bad.shape[0]))
            t, x, y, second = t[~out], x[~out], y[~out], second[~out]
        if self.held is not None:
            t, x, y, second = (np.concatenate(a) for a in zip(self.held, (t, x, y, second)))
            self.held = None
        if t.shape[0] == 0:
            return []
        k = t.shape[0] if final else int(t.searchsorted(t[-1], "left"))
        if k < t.shape[0]:
            self.held = (t[k:].copy(), x[k:].copy(), y[k:].copy(), second[k:].copy())
        if k == 0:
            return []
        pkt = self.tiler.push(ExposurePacket, "exposures", t[:k], pos, x=x[:k], y=y[:k], second=second[:k])
        return [] if pkt is None else [pkt]

    def finish(self, pos: int) -> list[ExposurePacket]:
        """End of file: the crossings held back."""
        none = (np.empty(0, np.int64), np.empty(0, np.uint16), np.empty(0, np.uint16), np.empty(0, np.bool_),
                np.empty(0, np.int64))
        return self.push(*none, pos=pos, final=True)
