"""Prophesee RAW (EVT 2.0, EVT 3.0) and DAT writers, streaming.

Layouts as read by :mod:`tectum.sources.files.prophesee` (Prophesee's
documentation). The header names the format and ``% geometry WxH`` and ends
with ``% end``. Times that do not fit the format's counter from zero (EVT
2.0 and DAT: 2^32 µs, EVT 3.0: 2^23 µs, i.e. half their wrap range) are
written relative to ``% t0 T`` (µs, the first packet's start), which the
reader adds back. Encoders:

* EVT 2.0: an ``EV_TIME_HIGH`` word whenever ``t >> 6`` changes, then one
  CD_ON/CD_OFF word per event.
* EVT 3.0: ``EVT_TIME_HIGH`` (stepping at most 2^11 x 4096 µs at a time so the
  reader's wrap rule holds across long gaps, and through 0 at each 24-bit
  wrap as a sensor does: faery 0.7 misses a wrap that skips 0),
  ``EVT_TIME_LOW``, ``EVT_ADDR_Y`` when they change, and per event ``EVT_ADDR_X`` with its polarity; runs of
  events sharing time, row and polarity go as ``VECT_BASE_X`` + ``VECT_12``
  / ``VECT_8`` masks.
* DAT: EventCD records (type 12, size 8).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket

from ._common import FileSink, header_date

__all__ = ["Evt2Sink", "Evt3Sink", "DatSink", "encode_evt2", "encode_evt3"]


@njit(cache=True, nogil=True)
def encode_evt2(t, x, y, p, state, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """state[0] = last time high written (-1: none). Returns words used."""
    k = 0
    last = state[0]
    for i in range(t.shape[0]):
        th = t[i] >> 6
        if th != last:
            out[k] = np.uint32((8 << 28) | (th & 0x0FFFFFFF))
            k += 1
            last = th
        typ = 1 if p[i] > 0 else 0
        out[k] = np.uint32((typ << 28) | ((t[i] & 0x3F) << 22) | (np.int64(x[i]) << 11) | np.int64(y[i]))
        k += 1
    state[0] = last
    return k


@njit(cache=True, nogil=True)
def encode_evt3(t, x, y, p, state, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """state: 0 last time high (unrolled, -1 none), 1 last low, 2 last y (-1).
    Returns words used."""
    k = 0
    last_h = state[0]
    last_l = state[1]
    last_y = state[2]
    n = t.shape[0]
    i = 0
    while i < n:
        h = t[i] >> 12
        lo = t[i] & 0xFFF
        if h != last_h:
            if last_h >= 0:
                # steps of at most 2047 (the reader's wrap rule), landing on 0 at
                # each 24-bit wrap, as a sensor does (some readers need it)
                while h - last_h > 2047 or (h >> 12) != (last_h >> 12):
                    nxt = min(last_h + 2047, h)
                    if (nxt >> 12) != (last_h >> 12):
                        nxt = ((last_h >> 12) + 1) << 12
                    last_h = nxt
                    out[k] = np.uint16((0x8 << 12) | (last_h & 0xFFF))
                    k += 1
            if h != last_h or last_h < 0:
                out[k] = np.uint16((0x8 << 12) | (h & 0xFFF))
                k += 1
            last_h = h
            last_l = -1
        if lo != last_l:
            out[k] = np.uint16((0x6 << 12) | lo)
            k += 1
            last_l = lo
        if y[i] != last_y:
            out[k] = np.uint16(y[i] & 0x7FF)
            k += 1
            last_y = y[i]
        # a run sharing t, y, p with increasing x: vector words
        j = i + 1
        while j < n and t[j] == t[i] and y[j] == y[i] and p[j] == p[i] and x[j] > x[j - 1] and x[j] - x[i] < 256:
            j += 1
        pol = 1 if p[i] > 0 else 0
        if j - i >= 3:
            base = np.int64(x[i])
            span = np.int64(x[j - 1]) - base + 1
            out[k] = np.uint16((0x3 << 12) | (pol << 11) | base)
            k += 1
            m = i
            off = 0
            while off < span:
                nb = 12 if span - off > 8 else 8
                mask = np.int64(0)
                while m < j and np.int64(x[m]) - base < off + nb:
                    mask |= 1 << (np.int64(x[m]) - base - off)
                    m += 1
                out[k] = np.uint16(((0x4 if nb == 12 else 0x5) << 12) | mask)
                k += 1
                off += nb
            i = j
        else:
            out[k] = np.uint16((0x2 << 12) | (pol << 11) | np.int64(x[i]))
            k += 1
            i += 1
    state[0] = last_h
    state[1] = last_l
    state[2] = last_y
    return k


class _RawSink(FileSink):
    """Common part of the RAW writers: header with geometry and ``t0``."""

    stores_sensor = True

    evt_line = ""
    fmt_line = ""
    limit = 1 << 32

    def _t0(self, packet: EventPacket) -> int:
        first = int(packet.t[0]) if len(packet) else packet.t_start
        return packet.t_start if first >= self.limit else 0

    def _begin(self, packet: EventPacket) -> None:
        assert self.f is not None and self.sensor is not None
        w, h = self.sensor
        if w > 2048 or h > 2048:
            raise ValueError(f"{self.format} stores 11-bit coordinates: sensor {w}x{h} is too large")
        self.t0 = self._t0(packet)
        lines = [f"% date {header_date()}", self.evt_line, self.fmt_line, f"% geometry {w}x{h}",
                 "% integrator_name tectum"]
        if self.t0:
            lines.append(f"% t0 {self.t0}")
        lines.append("% end")
        self.f.write(("\n".join(lines) + "\n").encode())
        self.state = np.array([-1, -1, -1], np.int64)

    def _empty(self) -> None:
        raise ValueError(f"{self.format}: no events were written and the sensor size is unknown")

    def _times(self, packet: EventPacket) -> np.ndarray:
        t = packet.t - self.t0 if self.t0 else packet.t
        if len(t) and t[0] < 0:
            raise ValueError(f"time {int(packet.t[0])} µs is before the file's t0 {self.t0} µs")
        return t


class Evt2Sink(_RawSink):
    """Prophesee RAW EVT 2.0 writer (``.raw``; ``evt2`` sink name)."""

    name = "evt2"
    format = "evt2"
    title = "EVT 2.0"
    extensions = (".raw",)
    evt_line = "% evt 2.0"
    fmt_line = "% format EVT2"

    def _events(self, packet: EventPacket) -> None:
        assert self.f is not None
        out = np.empty(2 * len(packet), np.uint32)
        k = encode_evt2(self._times(packet), packet.x, packet.y, packet.p, self.state, out)
        self.f.write(out[:k].astype("<u4").tobytes())


class Evt3Sink(_RawSink):
    """Prophesee RAW EVT 3.0 writer (``.raw`` by default with ``format=evt3``;
    registered as ``evt3``, extension ``.evt3.raw``/``.evt3``)."""

    name = "evt3"
    format = "evt3"
    title = "EVT 3.0"
    extensions = (".evt3", ".evt3.raw")
    evt_line = "% evt 3.0"
    fmt_line = "% format EVT3"
    limit = 1 << 23

    def _events(self, packet: EventPacket) -> None:
        assert self.f is not None
        t = self._times(packet)
        gaps = 0
        if len(t):
            last = max(int(self.state[0]), 0)
            gaps = int((int(t[-1]) >> 12) - last) // 2047 + (int(t[-1]) >> 24) - (last >> 12) + 2
        out = np.empty(4 * len(packet) + gaps + 8, np.uint16)
        k = encode_evt3(t, packet.x, packet.y, packet.p, self.state, out)
        self.f.write(out[:k].astype("<u2").tobytes())


class DatSink(FileSink):
    """Prophesee ``.dat`` writer (EventCD records)."""

    name = "dat"
    format = "dat"
    title = "DAT"
    extensions = (".dat",)
    stores_sensor = True

    def _begin(self, packet: EventPacket) -> None:
        assert self.f is not None and self.sensor is not None
        w, h = self.sensor
        if w > 16384 or h > 16384:
            raise ValueError(f"DAT stores 14-bit coordinates: sensor {w}x{h} is too large")
        first = int(packet.t[0]) if len(packet) else packet.t_start
        self.t0 = packet.t_start if first >= (1 << 32) else 0
        lines = ["% Data file containing CD events", f"% Date {header_date()}", "% Version 2",
                 f"% Width {w}", f"% Height {h}"]
        if self.t0:
            lines.append(f"% t0 {self.t0}")
        self.f.write(("\n".join(lines) + "\n").encode() + bytes([12, 8]))

    def _events(self, packet: EventPacket) -> None:
        assert self.f is not None
        rec = np.empty((len(packet), 2), "<u4")
        t = packet.t - self.t0
        if len(t) and (t[0] < 0 or t[-1] >= (1 << 32)):
            raise ValueError("DAT time is 32-bit: the recording spans more than 71 minutes from its t0")
        rec[:, 0] = t
        rec[:, 1] = (packet.x.astype(np.uint32) | (packet.y.astype(np.uint32) << 14)
                     | ((packet.p > 0).astype(np.uint32) << 28))
        self.f.write(rec.tobytes())
