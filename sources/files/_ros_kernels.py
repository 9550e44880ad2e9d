"""Numba decoders for the event payloads found in ROS bags.

* ``dvs_msgs/EventArray`` events (``uint16 x, uint16 y, time ts, bool
  polarity``) straight from the serialized message bytes, ROS 1 (packed,
  13 bytes per event) or CDR (ROS 2: fields aligned to their size, counted
  from the byte after the 4-byte encapsulation header), without building a
  Python object per event.
* ``event_camera_msgs/EventPacket`` with encoding ``libcaer``: libcaer
  polarity events, 8 bytes each: uint32 data (bit 0 valid mark, bit 1
  polarity 1 = ON, bits 2-16 y, bits 17-31 x) and int32 timestamp (µs, low 31
  bits of the device clock); the message's ``time_base`` (ns) holds the host
  time of the device start plus the clock's high bits, and a timestamp
  falling inside a packet means the 31-bit clock rolled over (+2^31 µs).
* ``libcaer_cmp``: 16-bit words, code in bits 15-12: TIME_HIGH 0 (12 bits,
  time >> 12), TIME_LOW 1 (12 bits), ADDR_X 2 (11 bits), ADDR_Y 3 (11-bit y,
  bit 11 polarity: one event at the current x), VECT_BASE_Y 4 (11-bit y,
  bit 11 polarity), VECT_8 5 / VECT_12 6 (valid-bit masks for y = base + i,
  base then advances by 8 / 12). Time (µs) is ``time_base`` (ns) / 1000 plus
  ``(high << 12) | low``, which restarts at 0 in every packet.

Like :mod:`._kernels`, each returns counts and the index of the first bad
item (-1 when none) and never raises.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["dvs_events", "libcaer_events", "libcaer_cmp_events", "LIBCAER_CMP_STATE"]


@njit(cache=True, nogil=True, inline="always")
def _u(buf, i, nbytes, be):  # pragma: no cover - numba
    v = np.int64(0)
    for k in range(nbytes):
        b = np.int64(buf[i + (nbytes - 1 - k if be else k)])
        v |= b << (8 * k)
    return v


@njit(cache=True, nogil=True)
def dvs_events(buf, start, n, cdr, origin, be, t, x, y, p):  # pragma: no cover - numba
    """Decode ``n`` serialized ``dvs_msgs/Event`` from byte ``start``.

    ``cdr``: align fields (relative to ``origin``) as CDR does; else packed
    ROS 1. Returns the byte after the last event, or -1 if the buffer is too
    short. ``t`` in µs (ns truncated)."""
    i = start
    m = buf.shape[0]
    for k in range(n):
        if cdr:
            i += (i - origin) & 1
        if i + 4 > m:
            return -1
        x[k] = _u(buf, i, 2, be)
        y[k] = _u(buf, i + 2, 2, be)
        i += 4
        if cdr:
            i += (-(i - origin)) & 3
        if i + 9 > m:
            return -1
        sec = _u(buf, i, 4, be)
        if cdr and sec >= (np.int64(1) << 31):
            sec -= np.int64(1) << 32  # CDR time sec is int32
        nsec = _u(buf, i + 4, 4, be)
        t[k] = sec * 1_000_000 + nsec // 1000
        p[k] = 1 if buf[i + 8] else -1
        i += 9
    return i


@njit(cache=True, nogil=True)
def libcaer_events(raw, time_base_ns, t, x, y, p):  # pragma: no cover - numba
    """Decode libcaer polarity events (``raw`` uint8, little-endian);
    returns (n_events, n_invalid_marked, n_rollovers)."""
    n = 0
    inval = 0
    rolls = 0
    high = np.int64(time_base_ns)
    last = np.int64(-1)
    m = raw.shape[0] // 8
    for k in range(m):
        d = _u(raw, 8 * k, 4, False)
        ts = _u(raw, 8 * k + 4, 4, False) & 0x7FFFFFFF
        if last >= 0 and ts < last and last - ts > (np.int64(1) << 30):
            high += (np.int64(1) << 31) * 1000
            rolls += 1
        last = ts
        if (d & 1) == 0:
            inval += 1
            continue
        t[n] = (high + ts * 1000) // 1000
        y[n] = (d >> 2) & 0x7FFF
        x[n] = (d >> 17) & 0x7FFF
        p[n] = 1 if (d >> 1) & 1 else -1
        n += 1
    return n, inval, rolls


# state: 0 current x, 1 vector base y, 2 vector polarity (+-1)
LIBCAER_CMP_STATE = 3


@njit(cache=True, nogil=True)
def libcaer_cmp_events(words, time_base_us, state, t, x, y, p):  # pragma: no cover - numba
    """Decode one ``libcaer_cmp`` payload (uint16 words); returns
    (n_events, first bad word index or -1, n_bad)."""
    n = 0
    bad = -1
    nbad = 0
    high = np.int64(0)
    low = np.int64(0)
    cx = state[0]
    by = state[1]
    vp = state[2] if state[2] != 0 else -1
    for i in range(words.shape[0]):
        w = np.int64(words[i])
        code = w >> 12
        if code == 0:
            high = (w & 0xFFF) << 12
        elif code == 1:
            low = w & 0xFFF
        elif code == 2:
            cx = w & 0x7FF
        elif code == 3:
            t[n] = time_base_us + (high | low)
            x[n] = cx
            y[n] = w & 0x7FF
            p[n] = 1 if (w >> 11) & 1 else -1
            n += 1
        elif code == 4:
            by = w & 0x7FF
            vp = 1 if (w >> 11) & 1 else -1
        elif code == 5 or code == 6:
            nb = 8 if code == 5 else 12
            for b in range(nb):
                if (w >> b) & 1:
                    t[n] = time_base_us + (high | low)
                    x[n] = cx
                    y[n] = by + b
                    p[n] = vp
                    n += 1
            by += nb
        else:
            if bad < 0:
                bad = i
            nbad += 1
    state[0] = cx
    state[1] = by
    state[2] = vp
    return n, bad, nbad
