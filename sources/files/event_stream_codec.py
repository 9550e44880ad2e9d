"""Event Stream 2.x (``.es``) layout, side-neutral: the header and the
numba kernels the reader (:mod:`tectum.sources.files.event_stream`) and the
writer (:mod:`tectum.sinks.files.event_stream`) share.

The specification (neuromorphic-paris/event_stream, version 2.0): the bytes
``Event Stream``, major, minor and patch version, a type byte (0 generic,
1 DVS, 2 ATIS, 3 Asynchronous & Modular Display, 4 color), for DVS, ATIS and
color the sensor width and height (little-endian uint16), then a state
machine of bytes. DVS and ATIS events are 5 bytes: *byte 0* holds the time
since the previous event (µs; 7 bits and the polarity for DVS, 6 bits, the
polarity and ``is_tc`` for ATIS), then x and y as little-endian uint16.
Between events (idle state) special bytes may appear:

* DVS: ``0xFF`` *overflow* adds 127 µs, ``0xFE`` *reset* does nothing (it is
  written five at a time, so that one lands in the idle state after a bit
  error and re-aligns the reader).
* ATIS: ``0b111111xx`` adds ``xx`` x 63 µs (``0xFC``, ``xx = 0``, is the
  *reset*).

Times start at 0 (the format stores no time origin). The y axis points up:
``y = 0`` is the **bottom** row (sepia, the format's reference library, and
faery, which flips to ``height - 1 - y``); tectum's rows count from the top,
so both sides flip. An ATIS event with ``is_tc = 1`` is a threshold crossing,
half of an exposure measurement (``polarity`` says first or second).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["MAGIC", "HEADER_BYTES", "TYPES", "header", "decode", "encode_dvs", "STATE"]

MAGIC = b"Event Stream"
#: Bytes of a DVS/ATIS/color header: magic, 3 version bytes, type, width, height.
HEADER_BYTES = 20
#: Type byte -> name.
TYPES = {0: "generic", 1: "dvs", 2: "atis", 3: "display", 4: "color"}
DVS, ATIS = 1, 2

#: Decoder state slots: 0 phase (0 idle, 1-4 bytes of an event read), 1 time
#: (µs), 2 x, 3 raw y, 4 byte 0's low bits, 5 offset of the event's byte 0,
#: 6 ATIS threshold crossings in the buffer, 7 file offset of the buffer's first byte,
#: 8 and 9 the largest x and y of the buffer's events (-1: none).
STATE = 10


def header(kind: int, width: int, height: int) -> bytes:
    """The 20 header bytes of a version 2.0.0 DVS or ATIS file."""
    return MAGIC + bytes([2, 0, 0, kind]) + int(width).to_bytes(2, "little") + int(height).to_bytes(2, "little")


@njit(cache=True, nogil=True)
def decode(buf, state, atis, h, t, x, y, p, where, tc_t, tc_x, tc_y, tc_second, tc_where):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """Decode DVS (``atis`` False) or ATIS bytes ``buf`` on from ``state``
    (see :data:`STATE`, updated for the next buffer). Writes the
    change-detection events completed in ``buf``: time (µs), x, y flipped
    to a top-left origin (a raw y outside ``[0, h)`` is kept as it is, for
    the caller to report), polarity ±1 and the file offset of each event's
    byte 0; and the ATIS threshold crossings (time, x, y flipped, second
    or first half of the exposure, offset; their number in ``state[6]``). Returns
    the number of events written (each output holds ``len(buf) // 5 + 1``)."""
    phase = state[0]
    tt = state[1]
    xx = state[2]
    yy = state[3]
    low = state[4]
    start = state[5]
    crossings = 0
    base = state[7]
    top_x = -1
    top_y = -1
    n = 0
    for i in range(buf.shape[0]):
        b = np.int64(buf[i])
        if phase == 0:
            if atis:
                if b >= 0xFC:
                    tt += 63 * (b & 3)
                    continue
                tt += b >> 2
                low = b & 3
            else:
                if b == 0xFF:
                    tt += 127
                    continue
                if b == 0xFE:
                    continue
                tt += b >> 1
                low = (b & 1) << 1  # the polarity in bit 1, as ATIS has it
            start = base + i
            phase = 1
        elif phase == 1:
            xx = b
            phase = 2
        elif phase == 2:
            xx |= b << 8
            phase = 3
        elif phase == 3:
            yy = b
            phase = 4
        else:
            yy |= b << 8
            phase = 0
            if low & 1:
                tc_t[crossings] = tt
                tc_x[crossings] = xx
                tc_y[crossings] = h - 1 - yy if yy < h else yy
                tc_second[crossings] = (low & 2) != 0
                tc_where[crossings] = start
                crossings += 1
                continue
            t[n] = tt
            x[n] = xx
            y[n] = h - 1 - yy if yy < h else yy
            top_x = max(top_x, xx)
            top_y = max(top_y, y[n])
            p[n] = 1 if low & 2 else -1
            where[n] = start
            n += 1
    state[0] = phase
    state[1] = tt
    state[2] = xx
    state[3] = yy
    state[4] = low
    state[5] = start
    state[6] = crossings
    state[8] = top_x
    state[9] = top_y
    return n


@njit(cache=True, nogil=True)
def encode_dvs(t, x, y, p, h, state, out):  # type: ignore[no-untyped-def]  # pragma: no cover - numba
    """DVS bytes of events (``t`` µs from the file's origin, non-decreasing,
    from ``state[0]``, the previous event's time; y top-left, flipped to the
    format's bottom-left) into ``out``, which holds at least ``5 * len(t) +
    (t[-1] - state[0]) // 127`` bytes. Returns the bytes written."""
    last = state[0]
    k = 0
    for i in range(t.shape[0]):
        d = t[i] - last
        while d >= 127:
            out[k] = 0xFF
            k += 1
            d -= 127
        out[k] = (d << 1) | (1 if p[i] > 0 else 0)
        xx = np.int64(x[i])
        yy = h - 1 - np.int64(y[i])
        out[k + 1] = xx & 0xFF
        out[k + 2] = xx >> 8
        out[k + 3] = yy & 0xFF
        out[k + 4] = yy >> 8
        k += 5
        last = t[i]
    state[0] = last
    return k
