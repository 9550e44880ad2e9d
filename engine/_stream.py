"""Operations on streams of packets of any kind: concatenation (one stream,
consecutive packets), merging (several streams of one kind, by timestamp)
and empty packets shaped like a stream's."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from typing import TypeVar

import numpy as np

from ._packet import EventPacket, Packet
from ._samples import ResultPacket, SamplePacket
from .errors import PacketError

__all__ = ["concat", "merge", "empty_like", "interleave"]


P = TypeVar("P", bound=Packet)


def concat(packets: Iterable[P]) -> P:
    """Concatenate consecutive packets of one stream into one packet.

    The packets must be of one kind, in order (``next.t_start >= prev.t_end``)
    and, for events, of one sensor size with the same extra columns. The
    result covers ``[first.t_start, last.t_end)``. One packet is returned as
    is. Sample fields follow the kind's declaration (see
    :mod:`tectum._samples`): empty packets never decide a field's shape, and
    an optional float field absent from some packets is NaN there.
    """
    pkts = list(packets)
    if not pkts:
        raise ValueError("concat needs at least one packet")
    first = pkts[0]
    if len(pkts) == 1:
        return first
    for a, b in zip(pkts, pkts[1:]):
        if type(b) is not type(first):
            raise PacketError(f"cannot concatenate {type(first).__name__} with {type(b).__name__}")
        if b.t_start < a.t_end:
            raise PacketError(f"packets overlap: [{a.t_start}, {a.t_end}) then [{b.t_start}, {b.t_end})")
    return _join(pkts, first.t_start, pkts[-1].t_end, sort=False)  # type: ignore[return-value]


def merge(parts: Sequence[P], t_start: int, t_end: int) -> P:
    """Merge packets of one kind from several streams into one packet
    covering ``[t_start, t_end)``, sorted by time; equal timestamps keep the
    order of ``parts``."""
    if not parts:
        raise ValueError("merge needs at least one packet")
    first = parts[0]
    for q in parts:
        if type(q) is not type(first):
            raise PacketError(f"cannot merge {type(first).__name__} with {type(q).__name__}")
    return _join(list(parts), t_start, t_end, sort=len(parts) > 1)  # type: ignore[return-value]


def empty_like(pkt: P, t_start: int, t_end: int) -> P:
    """A packet with no samples of ``pkt``'s stream (same sensor, columns,
    field dtypes and shapes) covering ``[t_start, t_end)`` µs."""
    if isinstance(pkt, EventPacket):
        return EventPacket._trusted(pkt.t[:0], pkt.x[:0], pkt.y[:0], pkt.p[:0], pkt.sensor, int(t_start),
                                    int(max(t_end, t_start)),
                                    {k: v[:0] for k, v in pkt.columns.items()})  # type: ignore[return-value]
    assert isinstance(pkt, SamplePacket)
    return type(pkt).empty(t_start, t_end, like=pkt)  # type: ignore[return-value]


def interleave(primary: Iterable[Packet], others: Sequence[Iterable[Packet]]) -> Iterator[Packet]:
    """One source's streams in time order: before each packet of ``primary``
    (the events, usually), every other stream up to that packet's ``t_end``
    (a packet straddling it is split there), so that a consumer joining the
    streams by watermark never holds one stream back waiting for another.
    Each stream must be in order; what remains of the others follows the
    primary's last packet. Lazy: a stream's next packet is pulled only when
    the primary has reached its start."""
    iters = [iter(o) for o in others]
    held: list[Packet | None] = [None] * len(iters)

    def upto(k: int, t1: int | None) -> Iterator[Packet]:
        while True:
            q = held[k]
            if q is None:
                q = next(iters[k], None)
                if q is None:
                    return
            if t1 is not None and q.t_end > t1:
                if q.t_start < t1:
                    a, q = q.split_at(t1)
                    yield a
                held[k] = q
                return
            held[k] = None
            yield q

    for pkt in primary:
        for k in range(len(iters)):
            yield from upto(k, pkt.t_end)
        yield pkt
    for k in range(len(iters)):
        yield from upto(k, None)


def _join(pkts: Sequence[Packet], t0: int, t1: int, *, sort: bool) -> Packet:
    first = pkts[0]
    if isinstance(first, EventPacket):
        return _join_events(pkts, t0, t1, sort)  # type: ignore[arg-type]
    assert isinstance(first, SamplePacket)
    t = np.concatenate([q.t for q in pkts])
    data = _join_fields(pkts)  # type: ignore[arg-type]
    if sort:
        order = np.argsort(t, kind="stable")
        t = t[order]
        data = {k: v[order] for k, v in data.items()}
    if isinstance(first, ResultPacket):
        return ResultPacket(t, data["items"], t_start=t0, t_end=t1)
    return type(first)(t, t_start=t0, t_end=t1, **data)


def _join_events(pkts: list[EventPacket], t0: int, t1: int, sort: bool) -> EventPacket:
    first = pkts[0]
    names = frozenset(first.columns)
    for q in pkts:
        if q.sensor != first.sensor:
            raise PacketError(f"sensor sizes differ: {first.sensor} vs {q.sensor}")
        if frozenset(q.columns) != names:
            raise PacketError(f"extra columns differ: {sorted(names)} vs {sorted(q.columns)}")
    cat = {k: np.concatenate([q[k] for q in pkts]) for k in first.column_names}
    if sort:
        order = np.argsort(cat["t"], kind="stable")
        cat = {k: v[order] for k, v in cat.items()}
    return EventPacket(cat.pop("t"), cat.pop("x"), cat.pop("y"), cat.pop("p"),
                       sensor=first.sensor, t_start=t0, t_end=t1, columns=cat)


def _join_fields(pkts: list[SamplePacket]) -> dict[str, np.ndarray]:
    """Fields of consecutive sample packets, stacked. Empty packets never
    decide a field's shape; an optional float field missing from some
    packets is NaN in their rows; any other mismatch is a PacketError."""
    cls = type(pkts[0])
    names = list(dict.fromkeys(k for q in pkts for k in q.data))
    full = [q for q in pkts if len(q)]
    out: dict[str, np.ndarray] = {}
    for name in names:
        have = [q.data[name] for q in full if name in q.data]
        if not have:  # only empty packets had it: keep its empty form
            out[name] = next(q.data[name] for q in pkts if name in q.data)
            continue
        proto = have[0]
        shapes = {a.shape[1:] for a in have}
        if len(shapes) > 1:
            raise PacketError(f"{cls.__name__} field {name!r} changes shape within the stream: {sorted(shapes)}")
        parts = []
        for q in full:
            a = q.data.get(name)
            if a is None:
                spec = cls.fields.get(name)
                if spec is None or not spec.optional or proto.dtype.kind not in "fc":
                    raise PacketError(f"{cls.__name__} field {name!r} is in some packets of the stream and not in "
                                      "others (only optional float fields may be; their missing rows are NaN)")
                a = np.full((len(q), *proto.shape[1:]), np.nan, proto.dtype)
            parts.append(a)
        out[name] = np.concatenate(parts)
    return out
