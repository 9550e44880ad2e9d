"""Event Stream 2.0 writer (``.es``, DVS type), streaming.

Bytes as the specification gives them (layout in
:mod:`tectum.sources.files.event_stream_codec`): the 20-byte header (version
2.0.0, type 1, width and height), then per event its *overflow* bytes
(``0xFF``, 127 µs each) and 5 bytes: time since the previous event and
polarity, x, and y flipped to the format's bottom-left origin. The
reader gives back the same events.

The format stores no time origin and counts time from 0 in 127 µs steps
between events: times are written as they are unless the first event comes
after :data:`EventStreamSink.LIMIT` µs (more than 2 MiB of overflow bytes
before it), when they are written from the first packet's start, kept in
:attr:`EventStreamSink.t0` (the file cannot hold it). ATIS files are not
written: tectum's events carry no threshold crossings to put in them.
"""

from __future__ import annotations

import numpy as np

from tectum import EventPacket
from tectum.sources.files import event_stream_codec as C

from ._common import FileSink

__all__ = ["EventStreamSink"]


class EventStreamSink(FileSink):
    """Event Stream 2.0 DVS writer (``.es``; ``es`` sink name)."""

    name = "es"
    format = "event_stream"
    title = "Event Stream 2.0"
    extensions = (".es",)
    stores_sensor = True
    #: First-event times (µs) from which the file counts from the first packet's start.
    LIMIT = 1 << 28

    def _begin(self, packet: EventPacket) -> None:
        assert self.f is not None and self.sensor is not None
        w, h = self.sensor
        if w > 0xFFFF or h > 0xFFFF:
            raise ValueError(f"Event Stream stores 16-bit sizes: sensor {w}x{h} is too large")
        #: The time (µs) the file's 0 stands for.
        self.t0 = self._origin(packet, self.LIMIT, "Event Stream")
        self.f.write(C.header(C.DVS, w, h))
        self.state = np.zeros(1, np.int64)  # the previous event's time, from the file's origin

    def _events(self, packet: EventPacket) -> None:
        assert self.f is not None and self.sensor is not None
        t = packet.t - self.t0 if self.t0 else packet.t
        last = int(self.state[0])
        out = np.empty(5 * len(t) + (int(t[-1]) - last) // 127 + 1, np.uint8)
        k = C.encode_dvs(t, packet.x, packet.y, packet.p, self.sensor[1], self.state, out)
        self.f.write(out[:k].tobytes())

    def _empty(self) -> None:
        raise ValueError("Event Stream: no events were written and the sensor size is unknown")
