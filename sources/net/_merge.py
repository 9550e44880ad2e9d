"""Several senders' streams into the one stream a network source gives.

Each sender's packets arrive in its own time order (its receiver checks
that); the :class:`Merger` releases, for every stream kind, the span up to
the *watermark* ``W``: the smallest time every live sender has passed (per
sender, the least ``t_end`` over the kinds it has sent). What lies before
``W`` can no longer be preceded by anything a live sender sends, so it goes
out merged by time (equal timestamps in the order senders joined). A sender
that has joined but sent nothing yet holds everything back (its first
packet may be early); one that has left holds nothing back and its pending
data go out as the others pass them, or all at once when no sender is
live. The output never goes back in time: a packet (or its part) from
before what was already released is dropped and counted in :attr:`behind`
(samples, events and ticks alike; a sender that joins after others have
passed its times loses that part).

Memory: what is pending is what live senders have sent beyond the slowest
one's watermark. Above ``max_pending`` samples the slowest live senders are
no longer waited for (counted in :attr:`forced`): the output moves on to the
watermark of the senders that have data pending, and what the slow ones
send later before it is dropped as behind.
"""

from __future__ import annotations

from tectum import EventPacket, Packet, concat, merge

__all__ = ["Merger", "event_schema"]


def event_schema(pkt: EventPacket) -> tuple[tuple[int, int], tuple[tuple[str, str], ...]]:
    """Sensor size and extra columns (names, dtypes) of an event packet:
    packets of two schemas cannot be merged into one stream."""
    return pkt.sensor, tuple((k, v.dtype.str) for k, v in pkt.columns.items())


class Merger:
    """Merge sender streams by watermark (see the module docstring).

    Senders are small integer ids: :meth:`join`, :meth:`add` their packets,
    :meth:`leave`; :meth:`release` gives what may go out, :meth:`flush`
    everything at the end."""

    def __init__(self, max_pending: int = 1 << 24) -> None:
        self.max_pending = max_pending
        self.behind = 0  #: samples (events included) dropped: before what was already released
        self.forced = 0  #: releases made without waiting for a slow sender
        self.schema: tuple[tuple[int, int], tuple[tuple[str, str], ...]] | None = None
        self._out_end: dict[type, int] = {}
        self._pending: dict[int, dict[type, list[Packet]]] = {}
        self._marks: dict[int, dict[type, int]] = {}
        self._live: list[int] = []
        self._count = 0
        self.refused = False

    def join(self, sid: int) -> None:
        self._live.append(sid)
        self._pending.setdefault(sid, {})
        self._marks.setdefault(sid, {})

    def leave(self, sid: int) -> None:
        if sid in self._live:
            self._live.remove(sid)

    def fits(self, pkt: EventPacket) -> bool:
        """False when ``pkt``'s sensor or columns differ from the stream's
        (the first events added fix them)."""
        return self.schema is None or event_schema(pkt) == self.schema

    def _fit(self, pkt: Packet) -> bool:
        """False for events of another schema than the stream's (the first
        events fix it)."""
        if not isinstance(pkt, EventPacket):
            return True
        if not self.fits(pkt):
            return False
        if self.schema is None and len(pkt):
            self.schema = event_schema(pkt)
        return True

    def _trim(self, pkt: Packet) -> Packet | None:
        """``pkt`` without what lies before the output's time (counted);
        None when nothing is left."""
        end = self._out_end.get(type(pkt))
        if end is None or pkt.t_start >= end:
            return pkt
        keep = pkt.slice_time(end, None)
        self.behind += len(pkt) - len(keep)
        return keep if keep.t_end > keep.t_start else None

    def add(self, sid: int, pkt: Packet) -> bool:
        """A packet of sender ``sid`` (in its own time order); False (and
        nothing added) for events whose schema is not the stream's."""
        if not self._fit(pkt):
            return False
        kept = self._trim(pkt)
        if kept is not None:
            self._marks[sid][type(kept)] = kept.t_end
            self._pending[sid].setdefault(type(kept), []).append(kept)
            self._count += len(kept)
        return True

    def through(self, sid: int, pkt: Packet) -> Packet | None:
        """The fast path of a lone sender with nothing pending: ``pkt`` goes
        straight out (trimmed to the output's time; None when nothing is
        left of it or it does not fit). Otherwise it is added as by
        :meth:`add` (None). :attr:`refused` tells whether it did not fit."""
        if self._live != [sid] or any(q for d in self._pending.values() for q in d.values()):
            self.refused = not self.add(sid, pkt)
            return None
        self.refused = not self._fit(pkt)
        kept = None if self.refused else self._trim(pkt)
        if kept is None:
            return None
        kind = type(kept)
        end = self._out_end.get(kind)
        if end is not None and kept.t_start > end:  # a gap (a new sender): the output covers it
            kept = kept._take_slice(0, len(kept), end, kept.t_end)
        self._out_end[kind] = self._marks[sid][kind] = kept.t_end
        return kept

    def _watermark(self) -> int | None:
        marks = [min(m.values()) if m else None for m in (self._marks[s] for s in self._live)]
        if not self._live:
            return self._last_end()
        if None not in marks:
            return min(marks)  # type: ignore[type-var]  # no None left
        if self._count <= self.max_pending:
            return None
        self.forced += 1
        busy = [min(self._marks[s].values()) for s in self._live if any(self._pending[s].values())]
        return min(busy) if busy else None

    def _last_end(self) -> int | None:
        ends = [q[-1].t_end for d in self._pending.values() for q in d.values() if q]
        return max(ends) if ends else None

    def release(self) -> list[Packet]:
        """What may go out now: per kind one packet, sample kinds before
        events (so no kind runs ahead of another)."""
        w = self._watermark()
        return [] if w is None else self._cut(w)

    def flush(self) -> list[Packet]:
        """Everything pending (the end of the run)."""
        w = self._last_end()
        return [] if w is None else self._cut(w)

    def _cut(self, w: int) -> list[Packet]:
        out: list[Packet] = []
        kinds = {k for d in self._pending.values() for k, q in d.items() if q}
        for kind in sorted(kinds, key=lambda k: (k is EventPacket, k.__name__)):
            parts: list[Packet] = []
            for d in self._pending.values():
                q = d.get(kind)
                if not q or q[0].t_start >= w:
                    continue
                whole = concat(q) if len(q) > 1 else q[0]
                a, b = whole.split_at(w)
                parts.append(a)
                d[kind] = [b] if b.t_end > b.t_start or len(b) else []
                self._count -= len(a)
            if parts:
                out.append(self._joined(kind, parts))
        for sid in [s for s, d in self._pending.items() if s not in self._live and not any(d.values())]:
            del self._pending[sid], self._marks[sid]  # gone, and nothing of it left
        return out

    def _joined(self, kind: type, parts: list[Packet]) -> Packet:
        start = self._out_end.get(kind, min(p.t_start for p in parts))
        end = max(p.t_end for p in parts)
        self._out_end[kind] = end
        if kind is EventPacket and self.schema is not None:  # ticks of another sensor (before it was fixed)
            parts = [p for p in parts if isinstance(p, EventPacket) and event_schema(p) == self.schema] or parts[:1]
        if len(parts) == 1:
            p = parts[0]
            one = p if (p.t_start, p.t_end) == (start, end) else p._take_slice(0, len(p), start, end)
        else:
            one = merge(parts, start, end)
        return one
