"""Where data enters: validate packets, or repair them and count repairs."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._packet import EventPacket, Kind, Packet
from .errors import PacketError

__all__ = ["Guard", "Repair"]

_EVENTS = Kind.EVENTS
_NONE = -(1 << 63)  # no events mark yet (below any int64 µs)


class Guard:
    """Checks every packet a source emits: the packet contract, and that the
    stream moves forward (``next.t_start >= prev.t_end`` per kind).

    Event packets go through :meth:`EventPacket.validate`, one compiled pass;
    a packet the source already validated (or a view of one: it is marked
    :attr:`~EventPacket.checked`) is not checked twice.

    Raises :class:`PacketError` naming the source and the bad event.
    """

    def __init__(self, source: str) -> None:
        self.source = source
        self._marks: dict[str, int] = {}  # other kinds'
        #: where the last events packet ended (µs; below any time before
        #: the first): the next one may not start before it
        self.events_mark = _NONE

    def __call__(self, pkt: Packet) -> Packet:
        if type(pkt) is EventPacket and pkt._checked and pkt.t_start >= self.events_mark:
            self.events_mark = pkt.t_end  # validated by the source: only the order to see
            return pkt
        try:
            if isinstance(pkt, EventPacket):
                pkt.validate()
            else:
                pkt._check_times()
            prev = self.events_mark if pkt.kind is _EVENTS else self._marks.get(pkt.kind, _NONE)
            if pkt.t_start < prev:
                raise PacketError(
                    f"{pkt.kind} packet [{pkt.t_start}, {pkt.t_end}) starts before the previous one "
                    f"ended ({prev} µs): time went backwards"
                )
        except PacketError as e:
            raise PacketError(f"source {self.source!r}: {e}", index=e.index) from None
        if pkt.kind is _EVENTS:
            self.events_mark = pkt.t_end
        else:
            self._marks[pkt.kind] = pkt.t_end
        return pkt


@dataclass
class Repair:
    """Repairs an event stream instead of rejecting it.

    * events outside the sensor or with a polarity other than ±1 are dropped;
    * events are re-sorted within a bounded window of ``window_us`` µs: an
      event is held until the newest timestamp seen is ``window_us`` past it,
      so disorder up to that much is fixed; events arriving later than that
      (behind what was already released) are dropped.

    Every repair is counted in :attr:`counts` (``out_of_bounds``,
    ``bad_polarity``, ``reordered``, ``late``). Memory is bounded by the
    events of one window.
    """

    window_us: int = 1000
    counts: dict[str, int] = field(default_factory=lambda: {
        "out_of_bounds": 0, "bad_polarity": 0, "reordered": 0, "late": 0})
    _held: EventPacket | None = None
    _released: int | None = None
    _newest: int | None = None

    def __call__(self, pkt: Packet) -> list[Packet]:
        """The repaired events of ``pkt`` that are ready (other kinds pass as they are)."""
        if not isinstance(pkt, EventPacket):
            return [pkt]
        w, h = pkt.sensor
        ok_xy = (pkt.x < w) & (pkt.y < h)
        ok_p = (pkt.p == 1) | (pkt.p == -1)
        self.counts["out_of_bounds"] += int((~ok_xy).sum())
        self.counts["bad_polarity"] += int((ok_xy & ~ok_p).sum())
        t = pkt.t
        keep = ok_xy & ok_p
        if self._released is not None:
            late = keep & (t < self._released)
            self.counts["late"] += int(late.sum())
            keep &= ~late
        cols = {k: v[keep] for k, v in pkt.columns.items()}
        tt, xx, yy, pp = t[keep], pkt.x[keep], pkt.y[keep], pkt.p[keep]
        if tt.size > 1:
            self.counts["reordered"] += int((tt[1:] < np.maximum.accumulate(tt)[:-1]).sum())
        if self._held is not None and len(self._held):
            h_ = self._held
            if tt.size and h_.t.size and tt[0] < h_.t[-1]:
                self.counts["reordered"] += int((tt < h_.t[-1]).sum())
            tt = np.concatenate([h_.t, tt])
            xx = np.concatenate([h_.x, xx])
            yy = np.concatenate([h_.y, yy])
            pp = np.concatenate([h_.p, pp])
            cols = {k: np.concatenate([h_.columns[k], v]) for k, v in cols.items()}
        order = np.argsort(tt, kind="stable")
        tt, xx, yy, pp = tt[order], xx[order], yy[order], pp[order]
        cols = {k: v[order] for k, v in cols.items()}
        newest = int(tt[-1]) if tt.size else None
        if newest is not None:
            self._newest = newest if self._newest is None else max(self._newest, newest)
        start = self._released if self._released is not None else (int(tt[0]) if tt.size else pkt.t_start)
        cut = (self._newest - self.window_us) if self._newest is not None else start
        cut = max(cut, start)
        i = int(np.searchsorted(tt, cut, side="left"))
        self._held = EventPacket(tt[i:], xx[i:], yy[i:], pp[i:], sensor=pkt.sensor,
                                 t_start=cut, t_end=max(cut, int(tt[-1]) + 1) if tt.size else cut,
                                 columns={k: v[i:] for k, v in cols.items()})
        if cut <= start:
            return []
        self._released = cut
        return [EventPacket(tt[:i], xx[:i], yy[:i], pp[:i], sensor=pkt.sensor, t_start=start, t_end=cut,
                            columns={k: v[:i] for k, v in cols.items()})]

    def flush(self) -> list[EventPacket]:
        """End of stream: release everything held."""
        h = self._held
        self._held = None
        if h is None or not len(h):
            return []
        start = self._released if self._released is not None else h.t_start
        self._released = h.t_end
        return [EventPacket(h.t, h.x, h.y, h.p, sensor=h.sensor, t_start=start, t_end=h.t_end,
                            columns=h.columns)]
