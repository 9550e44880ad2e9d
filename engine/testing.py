"""Test helpers for operator and plugin authors.

* :func:`assert_batch_invariant`: the conformance check every operator must
  pass: its output is identical whether the stream comes whole, event by
  event, or in any split into micro-batches (with empty ticks between).
  Uses hypothesis to draw the splits. Operators with named ports get one
  stream per port, split independently and interleaved in drawn orders.
* :func:`feed` and :func:`feed_ports`: drive an operator the way the engine
  does (process, on_tick, finish; ports joined by watermark).
* :class:`ListSource` and :class:`ListSink`: in-memory source and sink, so
  a short test covers an operator end to end in a real pipeline.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from ._operator import Operator, Sink, Source, as_packets
from ._packet import EventPacket, Kind, Packet
from ._stream import concat

__all__ = [
    "assert_batch_invariant",
    "feed_ports",
    "assert_streams_equal",
    "assert_stream_contract",
    "split_stream",
    "feed",
    "ListSource",
    "ListSink",
]


def _ticks(op: Operator) -> bool:
    return type(op).on_tick is not Operator.on_tick


def feed(op: Operator, packets: Sequence[Packet]) -> list[Packet]:
    """Push ``packets`` through a one-input ``op`` as the engine does
    (``process``, then ``on_tick`` with the packet's watermark), then end of
    stream; all outputs."""
    out: list[Packet] = []
    ticks = _ticks(op)
    for pkt in packets:
        out.extend(as_packets(op.process(pkt)))
        if ticks:
            out.extend(as_packets(op.on_tick(pkt.t_end)))
    out.extend(as_packets(op.finish()))
    return out


def feed_ports(op: Operator, streams: Mapping[str, Sequence[Packet]],
               order: Sequence[str] | None = None) -> list[Packet]:
    """Push each port's packets through an operator with named ports, joined
    by watermark as the engine joins them, then end every port; all outputs.

    ``order`` says which port's next packet goes in at each step (ports whose
    packets have run out are skipped); by default round robin. A port ends
    as soon as its last packet is in.
    """
    from ._graph import PortJoin

    join = PortJoin(streams)
    queues = {p: list(v) for p, v in streams.items()}
    out: list[Packet] = []
    ticks = _ticks(op)

    def run(batches: list[dict[str, Packet]]) -> None:
        for b in batches:
            out.extend(as_packets(op.process_ports(b)))
            if ticks:
                out.extend(as_packets(op.on_tick(next(iter(b.values())).t_end)))

    ended: set[str] = set()

    def step(port: str) -> None:
        if queues[port]:
            run(join.push(port, queues[port].pop(0)))
        if not queues[port] and port not in ended:
            ended.add(port)
            run(join.end(port))

    for port in order or ():
        if port in queues:
            step(port)
    while any(queues.values()) or len(ended) < len(queues):
        for port in queues:
            step(port)
    out.extend(as_packets(op.finish()))
    return out


def split_stream(packet: Packet, cuts: Sequence[int], ticks: Sequence[int] = ()) -> list[Packet]:
    """Split ``packet`` at the sample indices ``cuts`` (moved to the start of
    their timestamp's run, so equal timestamps stay together), then split the
    pieces again at the times ``ticks`` (µs), which makes empty packets where
    nothing happens. The pieces' intervals tile the packet's interval."""
    t = packet.t
    bounds = sorted({int(np.searchsorted(t, t[c], side="left")) for c in cuts if 0 < c < len(t)})
    times = [packet.t_start] + [int(t[b]) for b in bounds] + [packet.t_end]
    times = sorted(set(times) | {int(x) for x in ticks if packet.t_start < x < packet.t_end})
    return [packet.slice_time(a, b) for a, b in zip(times, times[1:])] or [packet]


def event_by_event(packet: Packet) -> list[Packet]:
    """One packet per distinct timestamp."""
    return list(packet.batches(1))


def _collect(packets: Sequence[Packet]) -> dict[Kind, list[Packet]]:
    by: dict[Kind, list[Packet]] = {}
    for q in packets:
        by.setdefault(q.kind, []).append(q)
    return by


def _samples_equal(a: np.ndarray, b: np.ndarray) -> bool:
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype == object:
        return all(_item_equal(x, y) for x, y in zip(a, b))
    if a.dtype.kind in "fc":
        return bool(np.array_equal(a, b, equal_nan=True))
    return bool(np.array_equal(a, b))


def _item_equal(x: Any, y: Any) -> bool:
    if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
        return _samples_equal(np.asarray(x), np.asarray(y))
    if isinstance(x, dict) and isinstance(y, dict):
        return x.keys() == y.keys() and all(_item_equal(x[k], y[k]) for k in x)
    if isinstance(x, (list, tuple)) and isinstance(y, (list, tuple)):
        return len(x) == len(y) and all(_item_equal(a, b) for a, b in zip(x, y))
    return bool(x == y)


def _flatten(pkts: list[Packet]) -> dict[str, np.ndarray]:
    """All samples of one kind's packets, column by column (intervals ignored)."""
    first = pkts[0]
    if isinstance(first, EventPacket):
        names = first.column_names
        return {n: np.concatenate([q[n] for q in pkts]) for n in names}  # type: ignore[index]
    cols = {"t": np.concatenate([q.t for q in pkts])}
    for k in first.data:  # type: ignore[attr-defined]
        parts = [q.data[k] for q in pkts if len(q)]  # type: ignore[attr-defined]
        cols[k] = np.concatenate(parts) if parts else first.data[k][:0]  # type: ignore[attr-defined]
    return cols


def assert_streams_equal(expected: Sequence[Packet], got: Sequence[Packet], what: str = "") -> None:
    """Assert two output streams hold the same samples, kind by kind and
    column by column (bit-exact, NaN equal to NaN); packet boundaries and
    intervals may differ."""
    ea, ga = _collect(expected), _collect(got)
    kinds = {k for k, v in ea.items() if sum(map(len, v))} | {k for k, v in ga.items() if sum(map(len, v))}
    for k in kinds:
        if k not in ea or k not in ga:
            raise AssertionError(f"{what}: {k} output only in one of the runs")
        a, b = _flatten(ea[k]), _flatten(ga[k])
        if a.keys() != b.keys():
            raise AssertionError(f"{what}: {k} columns differ: {sorted(a)} vs {sorted(b)}")
        for name in a:
            if not _samples_equal(a[name], b[name]):
                n = min(len(a[name]), len(b[name]))
                diff = next((i for i in range(n) if not _item_equal(a[name][i], b[name][i])), n)
                raise AssertionError(
                    f"{what}: {k} column {name!r} differs (lengths {len(a[name])} vs {len(b[name])}, "
                    f"first difference at sample {diff})"
                )


def assert_stream_contract(packets: Sequence[Packet]) -> None:
    """Assert that consecutive packets of one stream keep the packet
    contract: each valid, intervals back to back (``next.t_start ==
    prev.t_end``) and no timestamp split across two packets. For checking
    what a source emits."""
    for q in packets:
        if isinstance(q, EventPacket):
            q.validate()
        else:
            q._check_times()
    for a, b in zip(packets, packets[1:]):
        if a.t_end != b.t_start:
            raise AssertionError(f"gap or overlap: [{a.t_start}, {a.t_end}) then [{b.t_start}, {b.t_end})")
        if len(a) and len(b) and not a.t[-1] < b.t[0]:
            raise AssertionError(f"timestamp {int(b.t[0])} µs is split across two packets")


def assert_batch_invariant(
    factory: Callable[[], Operator],
    stream: Packet | Mapping[str, Packet],
    *,
    max_examples: int = 20,
    event_by_event_check: bool = True,
) -> None:
    """The batch-invariance conformance check.

    ``factory`` makes a fresh operator; ``stream`` is the whole input as one
    packet, or for an operator with named ports one packet per port. The
    output for the whole input is the reference; the operator must produce
    the same samples fed one timestamp at a time and fed in hypothesis-drawn
    splits with empty ticks in between (per port, independently, the ports
    interleaved in a drawn order).
    """
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    if isinstance(stream, Mapping):
        _assert_ports_invariant(factory, stream, max_examples, event_by_event_check)
        return

    reference = feed(factory(), [stream])
    n = len(stream)
    if event_by_event_check:
        assert_streams_equal(reference, feed(factory(), event_by_event(stream)), "event by event")

    span = max(stream.t_end - stream.t_start, 1)

    @settings(max_examples=max_examples, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(
        cuts=st.lists(st.integers(0, max(n - 1, 0)), max_size=30),
        ticks=st.lists(st.integers(stream.t_start, stream.t_start + span), max_size=8),
    )
    def check(cuts: list[int], ticks: list[int]) -> None:
        pieces = split_stream(stream, cuts, ticks)
        assert_streams_equal(reference, feed(factory(), pieces), f"split into {len(pieces)} packets")

    check()


class ListSource(Source):
    """Emits the given packets (already validated) and ends."""

    name = "list"

    def __init__(self, packets: Sequence[Packet], produces: Sequence[Kind] | None = None) -> None:
        self._packets = list(packets)
        kinds = tuple(produces) if produces else tuple(dict.fromkeys(p.kind for p in self._packets)) or (Kind.EVENTS,)
        self.produces = kinds  # type: ignore[misc]

    def packets(self) -> Iterator[Packet]:
        yield from self._packets


class ListSink(Sink):
    """Keeps every packet it receives in :attr:`packets` (all kinds)."""

    name = "list"
    consumes = (Kind.ANY,)

    def __init__(self) -> None:
        self.packets: list[Packet] = []
        self.closed = False
        self.aborted = False

    def write(self, packet: Packet) -> None:
        self.packets.append(packet)

    def close(self) -> None:
        self.closed = True

    def abort(self) -> None:
        self.aborted = True

    def events(self) -> EventPacket:
        """Every event received, as one packet."""
        ev = [p for p in self.packets if isinstance(p, EventPacket)]
        return concat(ev)



def _assert_ports_invariant(factory: Callable[[], Operator], streams: Mapping[str, Packet], max_examples: int,
                            event_by_event_check: bool) -> None:
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    ports = list(streams)
    reference = feed_ports(factory(), {p: [q] for p, q in streams.items()})
    if event_by_event_check:
        got = feed_ports(factory(), {p: event_by_event(q) for p, q in streams.items()})
        assert_streams_equal(reference, got, "every port event by event")

    def port_splits(p: str) -> Any:
        q = streams[p]
        span = max(q.t_end - q.t_start, 1)
        return st.tuples(st.lists(st.integers(0, max(len(q) - 1, 0)), max_size=20),
                         st.lists(st.integers(q.t_start, q.t_start + span), max_size=6))

    @settings(max_examples=max_examples, deadline=None, derandomize=True,
              suppress_health_check=list(HealthCheck))
    @given(splits=st.fixed_dictionaries({p: port_splits(p) for p in ports}),
           order=st.lists(st.sampled_from(ports), max_size=60))
    def check(splits: dict[str, tuple[list[int], list[int]]], order: list[str]) -> None:
        pieces = {p: split_stream(streams[p], *splits[p]) for p in ports}
        what = ", ".join(f"{p} in {len(v)}" for p, v in pieces.items())
        assert_streams_equal(reference, feed_ports(factory(), pieces, order), f"ports split ({what})")

    check()
