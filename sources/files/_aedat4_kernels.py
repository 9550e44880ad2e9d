"""Numba FlatBuffer walkers for AEDAT 4.0 packets, many packets per call.

A file holds thousands of small packets: looking up each packet's fields in
Python cost more than decoding the events. :func:`fill_events` decodes one
packet straight into a batch's preallocated columns (no per-packet arrays,
no joined copy); :func:`table_fields` takes one buffer holding many
decompressed, size-prefixed FlatBuffers (``offs[k]`` to ``ends[k]``). The
table/vtable/vector look-ups are bounds-checked in compiled code and never
raise: a malformed packet is reported.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["fill_events", "table_fields"]


@njit(cache=True, nogil=True, inline="always")
def _u32(buf, i):  # pragma: no cover - numba
    return (np.int64(buf[i]) | (np.int64(buf[i + 1]) << 8) | (np.int64(buf[i + 2]) << 16)
            | (np.int64(buf[i + 3]) << 24))


@njit(cache=True, nogil=True, inline="always")
def _u16(buf, i):  # pragma: no cover - numba
    return np.int64(buf[i]) | (np.int64(buf[i + 1]) << 8)


@njit(cache=True, nogil=True)
def _root_field(buf, lo, hi, field):  # pragma: no cover - numba
    """(table position, field position or 0 when absent); -1 table when the
    buffer ``[lo, hi)`` is not a well-formed size-prefixed FlatBuffer."""
    if hi - lo < 12 or _u32(buf, lo) + 4 > hi - lo:
        return -1, 0
    tab = lo + 4 + _u32(buf, lo + 4)
    if tab + 4 > hi:
        return -1, 0
    so = _u32(buf, tab)
    if so >= np.int64(1) << 31:
        so -= np.int64(1) << 32
    vt = tab - so
    if vt < lo or vt + 4 > hi:
        return -1, 0
    vsize = _u16(buf, vt)
    if vsize < 4 or vsize & 1 or vt + vsize > hi:
        return -1, 0
    if 4 + 2 * field + 2 > vsize:
        return tab, 0
    off = _u16(buf, vt + 4 + 2 * field)
    if off == 0:
        return tab, 0
    return tab, tab + off


@njit(cache=True, nogil=True)
def _vector(buf, lo, hi, field, elem):  # pragma: no cover - numba
    """(first element position, length) of root vector ``field``; length -1
    when malformed."""
    tab, at = _root_field(buf, lo, hi, field)
    if tab < 0:
        return 0, -1
    if at == 0:
        return 0, 0
    if at + 4 > hi:
        return 0, -1
    vec = at + _u32(buf, at)
    if vec + 4 > hi:
        return 0, -1
    n = _u32(buf, vec)
    if vec + 4 + n * elem > hi:
        return 0, -1
    return vec + 4, n


@njit(cache=True, nogil=True)
def fill_events(buf, o, t, x, y, p):  # pragma: no cover - numba
    """Split the ``Event`` structs (int64 t, int16 x, int16 y, bool polarity)
    of one EventPacket FlatBuffer into the columns from index ``o``; returns
    the number of events, or -1 when the buffer is malformed or the columns
    are too short."""
    s, n = _vector(buf, 0, buf.shape[0], 0, 16)
    if n < 0 or o + n > t.shape[0]:
        return -1
    if s % 8 == 0:  # aligned, as FlatBuffers write it: whole-word loads
        q = buf[s:s + 16 * n].view(np.int64)
        h = buf[s:s + 16 * n].view(np.uint16)
        for i in range(n):
            t[o + i] = q[2 * i]
            x[o + i] = h[8 * i + 4]
            y[o + i] = h[8 * i + 5]
            p[o + i] = 1 if buf[s + 16 * i + 12] else -1
        return n
    b = s
    for i in range(o, o + n):
        v = np.int64(0)
        for j in range(8):
            v |= np.int64(buf[b + j]) << (8 * j)
        t[i] = v
        x[i] = _u16(buf, b + 8)
        y[i] = _u16(buf, b + 10)
        p[i] = 1 if buf[b + 12] else -1
        b += 16
    return n


@njit(cache=True, nogil=True)
def _tables(buf, lo, hi, fields, sizes, pos, row):  # pragma: no cover - numba
    """Fill ``pos`` from ``row`` with the field positions of the root's
    vector of tables in ``[lo, hi)``; returns the next row, -1 if malformed."""
    s, n = _vector(buf, lo, hi, 0, 4)
    if n < 0:
        return -1
    for i in range(n):
        if pos.shape[0] > 0:
            tab = s + 4 * i + _u32(buf, s + 4 * i)
            if tab + 4 > hi:
                return -1
            so = _u32(buf, tab)
            if so >= np.int64(1) << 31:
                so -= np.int64(1) << 32
            vt = tab - so
            if vt < lo or vt + 4 > hi:
                return -1
            vsize = _u16(buf, vt)
            if vsize < 4 or vsize & 1 or vt + vsize > hi:
                return -1
            for j in range(fields.shape[0]):
                pos[row, j] = -1
                if 4 + 2 * fields[j] + 2 <= vsize:
                    off = _u16(buf, vt + 4 + 2 * fields[j])
                    if off != 0:
                        if tab + off + sizes[j] > hi:
                            return -1
                        pos[row, j] = tab + off
        row += 1
    return row


@njit(cache=True, nogil=True)
def table_fields(buf, offs, ends, fields, sizes):  # pragma: no cover - numba
    """For packets whose root field 0 is a vector of tables (IMU, triggers):
    the byte position of each table's ``fields[j]`` (``sizes[j]`` bytes; -1
    when absent), all packets' tables in one array. Returns (positions
    (n, len(fields)), rows per packet, first malformed packet or -1)."""
    rows = np.zeros(offs.shape[0], np.int64)
    probe = np.zeros((0, fields.shape[0]), np.int64)
    total = 0
    for k in range(offs.shape[0]):
        r = _tables(buf, offs[k], ends[k], fields, sizes, probe, 0)
        if r < 0:
            return probe, rows, k
        rows[k] = r
        total += r
    pos = np.empty((total, fields.shape[0]), np.int64)
    row = 0
    for k in range(offs.shape[0]):
        row = _tables(buf, offs[k], ends[k], fields, sizes, pos, row)
        if row < 0:
            return probe, rows, k
    return pos, rows, -1
