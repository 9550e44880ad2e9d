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


@njit(cache=True, nogil=True)
def background_activity_select(t, x, y, p, last, base, dt_us, ot, ox, oy, op, idx, want_idx):  # type: ignore[no-untyped-def]
    """The filter of :func:`background_activity_kernel`, fused with the
    selection of its output: event ``i`` is kept when the latest time one
    of its 8 neighbours fired is at or after ``t[i] - dt_us``. ``last`` is
    a ``(1, H + 2, W + 2)`` padded map (int32 or int64) of each pixel's own
    latest time, relative to ``base`` µs (8 reads and one write per event:
    reads run in parallel, writes queue). Kept events are written to the
    front of ``ot, ox, oy, op`` (one spare slot each: the write is
    branch-free) and, with ``want_idx``, their input indices to ``idx``;
    returns how many were kept."""
    m = last[0]
    n = 0
    for i in range(t.shape[0]):
        ti = t[i]
        xi = x[i]
        yi = y[i]
        xx = np.intp(xi) + 1
        yy = np.intp(yi) + 1
        a = max(m[yy - 1, xx - 1], m[yy - 1, xx])
        b = max(m[yy - 1, xx + 1], m[yy, xx - 1])
        c = max(m[yy, xx + 1], m[yy + 1, xx - 1])
        d = max(m[yy + 1, xx], m[yy + 1, xx + 1])
        ok = np.int64(max(max(a, b), max(c, d))) + base >= ti - dt_us
        ot[n] = ti
        ox[n] = xi
        oy[n] = yi
        op[n] = p[i]
        if want_idx:
            idx[n] = i
        n += int(ok)
        m[yy, xx] = ti - base
    return n


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
    selects in one pass (:func:`background_activity_select`).
    """

    name = "filter.background_activity"

    def __init__(self, dt_us: int = 6000) -> None:
        if dt_us < 0:
            raise ValueError("dt_us must be >= 0")
        self.dt_us = int(dt_us)
        self.last: np.ndarray | None = None
        self.base = 0  # µs: the origin of the times in ``last``

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
        n = background_activity_select(packet.t, packet.x, packet.y, packet.p, self.last, self.base, self.dt_us,
                                       ot, ox, oy, op, idx, bool(cols))
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
