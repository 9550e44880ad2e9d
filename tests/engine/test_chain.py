"""A source's straight line of operators (:class:`tectum._graph.Chain`) runs
as one loop: the same calls, outputs and counts as the plain path, whatever
the operators return."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import tectum
from tectum import EventPacket, ImuPacket, Kind
from tectum._graph import Graph
from tectum.testing import ListSink, ListSource


def _events(n: int = 300, runs: bool = False) -> EventPacket:
    rng = np.random.default_rng(1)
    t = np.sort(rng.integers(0, n // 2, n)) if runs else np.arange(n) * 3
    return EventPacket(t.astype(np.int64), rng.integers(0, 8, n).astype(np.uint16),
                       rng.integers(0, 6, n).astype(np.uint16), np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8),
                       sensor=(8, 6), t_start=0, t_end=int(t[-1]) + 1).validate()


class _Varied(tectum.Operator):
    """Returns, by the packet's first timestamp, one packet in a list (the
    chain's own case), nothing, two packets, a bare packet, a tuple, None,
    an IMU packet beside the events, or raises at ``fail_at`` µs."""

    name = "filter.varied_chain_test"
    produces = (Kind.EVENTS, Kind.IMU)

    def __init__(self, phase: int = 0, fail_at: int = -1) -> None:
        self.phase, self.fail_at, self.calls = phase, fail_at, 0

    def process(self, packet: EventPacket) -> Any:
        self.calls += 1
        t0 = int(packet.t[0]) if len(packet) else packet.t_start
        if t0 == self.fail_at:
            raise RuntimeError("boom")
        case = (t0 // 3 + self.phase) % 11
        if case == 1:
            return []
        if case == 2:
            return [packet, packet]
        if case == 3:
            return packet
        if case == 4:
            return (packet,)
        if case == 5:
            return None
        if case == 6:
            imu = ImuPacket(np.array([packet.t_start]), accel=np.zeros((1, 3)), gyro=np.zeros((1, 3)),
                            t_start=packet.t_start, t_end=packet.t_end)
            return [imu, packet]
        if case == 7:
            return iter([packet])  # a generator-like result
        return [packet]


class _Ticks(tectum.Operator):
    """Passes events on and acts on ticks (not part of a chain)."""

    name = "filter.ticks_chain_test"

    def process(self, packet: EventPacket) -> list[EventPacket]:
        return [packet]

    def on_tick(self, watermark: int) -> list[EventPacket]:
        return []


class _EventsOnly(tectum.Sink):
    """Takes events only (IMU reaching it is counted as not written)."""

    name = "events_only_chain_test"
    consumes = (Kind.EVENTS,)

    def __init__(self) -> None:
        self.packets: list[tectum.Packet] = []

    def write(self, packet: tectum.Packet) -> None:
        self.packets.append(packet)


def _build(pk: EventPacket, ops: list[tectum.Operator], sink: tectum.Sink, max_events: int) -> tectum.Pipeline:
    p = tectum.Pipeline(max_events=max_events)
    node = p.source(ListSource([pk]), id="src")
    for i, op in enumerate(ops):
        node = p.op(op, node, id=f"op{i}")
    p.sink(sink, node, id="sink")
    return p


def _run(pk: EventPacket, make: Any, max_events: int, chain: bool,
         monkeypatch: pytest.MonkeyPatch) -> tuple[tectum.Stats, list[tectum.Packet], list[int]]:
    ops, sink = make()
    with monkeypatch.context() as m:
        if not chain:
            m.setattr(Graph, "chain_of", lambda self, node_id: None)
        else:  # the chain must be in use
            real = Graph.chain_of
            m.setattr(Graph, "chain_of", lambda self, node_id: _must(real(self, node_id)))
        stats = tectum.run(_build(pk, ops, sink, max_events))
    return stats, sink.packets, [op.calls for op in ops if isinstance(op, _Varied)]


def _must(chain: Any) -> Any:
    assert chain is not None
    return chain


def _counts(stats: tectum.Stats) -> dict[str, tuple[Any, ...]]:
    return {nid: (s.packets_in, s.events_in, s.packets_out, s.events_out, s.samples_in, s.samples_out, s.not_written)
            for nid, s in stats.nodes.items()}


_ENDS = {
    "sink written through": lambda: ([_Varied(0), _Varied(4), _Varied(8)], ListSink()),
    "sink of some kinds": lambda: ([_Varied(0), _Varied(5)], _EventsOnly()),
    "an operator on ticks after the chain": lambda: ([_Varied(2), _Varied(7), _Ticks()], ListSink()),
    "one operator": lambda: ([_Varied(3)], ListSink()),
}


@pytest.mark.parametrize("end", list(_ENDS))
@pytest.mark.parametrize("max_events, runs", [(1, False), (1, True), (4, False)])
def test_a_chain_gives_what_the_plain_path_gives(end: str, max_events: int, runs: bool,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    pk = _events(runs=runs)
    plain, plain_out, plain_calls = _run(pk, _ENDS[end], max_events, False, monkeypatch)
    fast, fast_out, fast_calls = _run(pk, _ENDS[end], max_events, True, monkeypatch)
    assert fast_calls == plain_calls and min(fast_calls) > 10
    assert [(type(q), q.t_start, q.t_end) for q in fast_out] == [(type(q), q.t_start, q.t_end) for q in plain_out]
    assert all(np.array_equal(a.t, b.t) for a, b in zip(fast_out, plain_out))
    assert _counts(fast) == _counts(plain)
    assert fast.nodes["src"].packets_out == plain.nodes["src"].packets_out > 10
    assert fast.latency["sink"].count == plain.latency["sink"].count == fast.nodes["sink"].packets_in
    for nid in ("op0", "sink"):
        assert fast.nodes[nid].busy_ns > 0


@pytest.mark.parametrize("where", ["op0", "op1", "op2", "sink"])
def test_an_error_in_a_chain_names_its_node(where: str) -> None:
    pk = _events()
    fail_at = int(pk.t[46])  # where every operator returns [packet]: the chain's own case

    class _Failing(ListSink):
        def write(self, packet: tectum.Packet) -> None:
            if len(packet) and int(packet.t[0]) == fail_at:
                raise RuntimeError("boom")
            super().write(packet)

    ops = [_Varied(9, fail_at if where == f"op{i}" else -1) for i in range(3)]
    with pytest.raises(tectum.NodeError, match=f"'{where}'.*boom") as err:
        tectum.run(_build(pk, ops, _Failing() if where == "sink" else ListSink(), 1))
    assert err.value.node == where


class _Costly(tectum.Operator):
    """Passes events on after ``cost`` ns of a fake clock; with ``twice``,
    every ``twice``-th packet goes out twice (the plain path's case)."""

    name = "filter.costly_chain_test"

    def __init__(self, clock: list[int], cost: int, twice: int = 0) -> None:
        self.clock, self.cost, self.twice, self.calls = clock, cost, twice, 0

    def process(self, packet: EventPacket) -> list[EventPacket]:
        self.clock[0] += self.cost
        self.calls += 1
        return [packet, packet] if self.twice and self.calls % self.twice == 0 else [packet]


def test_a_chain_times_each_step_exactly(monkeypatch: pytest.MonkeyPatch) -> None:
    """Busy time per node on a fake clock that only the steps and the
    cutting of pieces move: each node gets its own steps' time, not the
    cutting's nor its neighbours', nor the plain path's after a step that
    hands two packets to it."""
    now = [0]
    pk = _events(1000)
    ops = [_Costly(now, 1), _Costly(now, 10, twice=5), _Costly(now, 100)]

    class _Sink(ListSink):
        def write(self, packet: tectum.Packet) -> None:
            now[0] += 1000
            super().write(packet)

    cut = EventPacket.batches

    def batches(self: EventPacket, max_samples: int) -> Any:
        for piece in cut(self, max_samples):
            now[0] += 10**6  # making a piece: no node's time
            yield piece

    monkeypatch.setattr("tectum._graph.perf_counter_ns", lambda: now[0])
    monkeypatch.setattr("tectum._scheduler.perf_counter_ns", lambda: now[0])  # the sink written on the plain path
    monkeypatch.setattr(EventPacket, "batches", batches)
    sink = _Sink()
    real = Graph.chain_of
    monkeypatch.setattr(Graph, "chain_of", lambda self, node_id: _must(real(self, node_id)))
    stats = tectum.run(_build(pk, ops, sink, 1))
    n, out = len(pk), len(pk) + len(pk) // 5
    assert len(sink.packets) == out and ops[2].calls == out
    assert [stats.nodes[nid].busy_ns for nid in ("op0", "op1", "op2", "sink")] == [n, 10 * n, 100 * out, 1000 * out]
