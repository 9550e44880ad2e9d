"""``filter.background_activity``: Delbruck's background-activity filter."""

from __future__ import annotations

import numpy as np
from numba import njit

from tectum import EventPacket, Operator, concat

from ._state import padded_timestamps

__all__ = ["BackgroundActivity", "background_activity_kernel", "background_activity_select"]

#: Relative times (µs) in the operator's int32 state stay below this; a
#: stream running longer moves the state's origin on (:meth:`BackgroundActivity._rebase`).
_SPAN_US = 1 << 30
#: A pixel of the int32 state that has never fired (relative time).
_NEVER32 = np.iinfo(np.int32).min


@njit(cache=True, nogil=True)
def background_activity_kernel(t, x, y, support, dt_us, keep):  # type: ignore[no-untyped-def]
    """Keep event ``i`` when one of its 8 neighbours fired at or after
    ``t[i] - dt_us``. ``support`` is a ``(1, H + 2, W + 2)`` int64 padded
    map holding, per pixel, the latest time (µs) one of its 8 neighbours
    fired: every event, kept or not, writes its time into its neighbours'
    cells (one read and 8 writes per event, no branches, and since times
    never decrease the latest write is the maximum). Writes ``keep`` (bool);
    returns the number kept."""
    m = support[0]
    n = 0
    for i in range(t.shape[0]):
        ti = t[i]
        xx = np.intp(x[i]) + 1
        yy = np.intp(y[i]) + 1
        ok = m[yy, xx] >= ti - dt_us
        keep[i] = ok
        n += ok
        m[yy - 1, xx - 1] = ti
        m[yy - 1, xx] = ti
        m[yy - 1, xx + 1] = ti
        m[yy, xx - 1] = ti
        m[yy, xx + 1] = ti
        m[yy + 1, xx - 1] = ti
        m[yy + 1, xx] = ti
        m[yy + 1, xx + 1] = ti
    return n


@njit(cache=True, nogil=True, inline="always")
def _rows_max(m, a, b):  # type: ignore[no-untyped-def]
    """The latest of the three cells from ``a`` and the three from ``b`` of
    the flat map ``m`` (an event's neighbours on the rows above and below)."""
    one = np.uintp(1)
    two = np.uintp(2)
    return max(max(max(m[a], m[a + one]), max(m[a + two], m[b])), max(m[b + one], m[b + two]))


@njit(cache=True, nogil=True)
def background_activity_select(t, x, y, p, last, base, dt_us, ot, ox, oy, op, idx, want_idx, row_first):  # type: ignore[no-untyped-def]
    """The filter of :func:`background_activity_kernel`, fused with the
    selection of its output: event ``i`` is kept when the latest time one
    of its 8 neighbours fired is at or after ``t[i] - dt_us``. ``last`` is
    a ``(1, H + 2, W + 2)`` padded map (int32 or int64) of each pixel's own
    latest time, relative to ``base`` µs (read as one flat array with
    unsigned indices: no negative-index fix-ups; one write per event).
    Kept events are written to the front of ``ot, ox, oy, op`` (one spare
    slot each: the write is branch-free) and, with ``want_idx``, their
    input indices to ``idx``. Returns how many were kept and, with
    ``row_first`` (else 0), how many of them by a neighbour on their own
    row (left or right).

    Without ``row_first`` each event reads its 8 neighbours (three rows of
    the map) and takes their maximum, branch-free: the fastest when many
    events are dropped. With ``row_first`` it reads its left and right
    neighbours (its own row, the one its write touches) and reads the rows
    above and below only when neither is recent enough: when most events
    pass by a neighbour on their own row, most touch one row of the map
    instead of three (and the branch is predictable). Both keep the same
    events."""
    w2 = np.uintp(last.shape[2])
    m = last.reshape(-1)
    one = np.uintp(1)
    two = np.uintp(2)
    n = 0
    by_row = 0
    for i in range(t.shape[0]):
        ti = t[i]
        rel = ti - base
        lim = rel - dt_us
        xi = x[i]
        yi = y[i]
        c = (np.uintp(yi) + one) * w2 + np.uintp(xi)  # the left neighbour's cell; the pixel's is c + 1
        a, b = c - w2, c + w2  # the rows above and below
        mid = max(m[c], m[c + two])
        if row_first:
            ok = mid >= lim
            by_row += int(ok)
            if not ok:
                ok = _rows_max(m, a, b) >= lim
        else:
            ok = max(mid, _rows_max(m, a, b)) >= lim
        ot[n] = ti
        ox[n] = xi
        oy[n] = yi
        op[n] = p[i]
        if want_idx:
            idx[n] = i
        n += int(ok)
        m[c + one] = rel
    return n, by_row


#: The share of a packet's events kept above which the next packet is
#: filtered ``row_first`` (see :func:`background_activity_select`), and
#: the share kept by their own row it must keep then to stay so.
_ROW_FIRST_SHARE = 0.75
#: Packets filtered reading all 8 neighbours after one that did not keep
#: enough by their own row, before the next try (counting those in the
#: plain pass would cost it 6-12 %).
_ROW_FIRST_RETRY = 16


class BackgroundActivity(Operator):
    """Background-activity filter (Delbruck 2008): keep an event when at
    least one of its 8 neighbours fired within the last ``dt_us`` µs
    (inclusive); every event, kept or dropped, refreshes its pixel's time.

    Default ``dt_us = 6000``: an edge moving at 170 px/s or faster reaches
    the next pixel within 6 ms, so (measured on the ``pattern:`` bars at
    200 px/s) over 90 % of signal passes, while Poisson noise of rate ``r``
    Hz/px passes with probability ``1 - exp(-8 r dt)``: 9 % at 2 Hz/px.
    Slower scenes need a longer ``dt_us``.

    State: one int32 per pixel (the latest time it fired, relative to an
    origin that moves on every 2^30 µs) plus a one-pixel border,
    4 x (W + 2) x (H + 2) bytes (about 365 kB for 346x260; int64 and twice
    that for a ``dt_us`` of 2^29 µs or more). The kernel filters and
    selects in one pass (:func:`background_activity_select`); after a
    packet that kept over 75 % of its events, the next is filtered reading
    each event's own row first (the same events kept, faster when most
    pass by their own row), for as long as over 75 % pass by it.
    """

    name = "filter.background_activity"

    def __init__(self, dt_us: int = 6000) -> None:
        if dt_us < 0:
            raise ValueError("dt_us must be >= 0")
        self.dt_us = int(dt_us)
        self.last: np.ndarray | None = None
        self.base = 0  # µs: the origin of the times in ``last``
        self._row_first = False  # read each event's own row first (same output: see process)
        self._retry = 0  # packets left before row_first may be tried again

    def memory_us(self) -> int:
        """Only neighbours' times within ``dt_us`` count (time sharding)."""
        return self.dt_us

    def process(self, packet: EventPacket) -> list[EventPacket]:
        m = len(packet)
        if m == 0:
            return [packet]
        if self.last is None:
            self._start(packet)
        if packet.t_end - self.base > _SPAN_US and self.last.dtype == np.int32:  # type: ignore[union-attr]
            if packet.t_end - packet.t_start > _SPAN_US // 2:  # one packet spans minutes: in parts
                step = _SPAN_US // 4
                parts = [packet.slice_time(a, a + step) for a in range(packet.t_start, packet.t_end, step)]
                return [concat([q for part in parts for q in self.process(part)])]
            self._rebase(packet.t_start)
        cols = packet.columns
        ot, ox, oy = np.empty(m + 1, np.int64), np.empty(m + 1, np.uint16), np.empty(m + 1, np.uint16)
        op, idx = np.empty(m + 1, np.int8), np.empty(m + 1 if cols else 1, np.intp)
        n, by_row = background_activity_select(packet.t, packet.x, packet.y, packet.p, self.last, self.base,
                                               self.dt_us, ot, ox, oy, op, idx, bool(cols), self._row_first)
        if self._row_first:
            self._row_first = by_row > _ROW_FIRST_SHARE * m
            self._retry = 0 if self._row_first else _ROW_FIRST_RETRY
        else:
            self._retry = max(self._retry - 1, 0)
            self._row_first = not self._retry and n > _ROW_FIRST_SHARE * m
        if n == m:
            return [packet]
        return [EventPacket._trusted(ot[:n], ox[:n], oy[:n], op[:n], packet.sensor, packet.t_start, packet.t_end,
                                     {k: v[idx[:n]] for k, v in cols.items()}, packet.checked)]

    def _start(self, packet: EventPacket) -> None:
        """The state, at the first packet: int32 times relative to its start
        (int64 from 0 when ``dt_us`` reaches 2^29 µs)."""
        if self.dt_us < _SPAN_US // 2:
            w, h = packet.sensor
            self.last, self.base = np.full((1, h + 2, w + 2), _NEVER32, np.int32), packet.t_start
        else:
            self.last, self.base = padded_timestamps(packet.sensor), 0

    def _rebase(self, base: int) -> None:
        """Move the int32 state's origin on to ``base`` µs: times more than
        2^31 µs before it become "never" (far beyond ``dt_us``)."""
        shifted = self.last.astype(np.int64) - (base - self.base)  # type: ignore[union-attr]
        self.last = np.maximum(shifted, _NEVER32).astype(np.int32)
        self.base = base
