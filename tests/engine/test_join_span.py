"""``Operator.join_us``: the engine joins a source's small packets into runs
no longer than the least span the operators below ask for."""

from __future__ import annotations

import numpy as np
import pytest

import tectum
from tectum import EventPacket
from tectum.testing import ListSink, ListSource, assert_streams_equal


class _Spans(tectum.Operator):
    """Passes packets on and records the span (µs) of each it was given."""

    name = "filter.spans_join_test"

    def __init__(self, join: int | None = None) -> None:
        self.join = join
        self.spans: list[int] = []

    def join_us(self) -> int | None:
        return self.join

    def process(self, packet: EventPacket) -> list[EventPacket]:
        self.spans.append(packet.t_end - packet.t_start)
        return [packet]


def _stream(n: int = 20_000, duration_us: int = 200_000) -> EventPacket:
    rng = np.random.default_rng(3)
    t = np.sort(rng.integers(0, duration_us, n))
    return EventPacket.from_arrays(t, rng.integers(0, 32, n), rng.integers(0, 24, n), rng.choice([-1, 1], n),
                                   sensor=(32, 24), t_start=0, t_end=duration_us).validate()


def _pieces(ev: EventPacket, step: int, copies: bool) -> list[EventPacket]:
    cuts = [ev.slice_time(a, a + step) for a in range(0, ev.t_end, step)]
    if not copies:  # slices lying end to end in the same arrays (joined as a view)
        return cuts
    return [EventPacket(q.t.copy(), q.x.copy(), q.y.copy(), q.p.copy(), sensor=q.sensor, t_start=q.t_start,
                        t_end=q.t_end).validate() for q in cuts]  # small packets of their own (joined by a copy)


def _run(ops: list[_Spans], pieces: list[EventPacket]) -> list[tectum.Packet]:
    p = tectum.Pipeline()
    node = p.source(ListSource(pieces), id="src")
    for i, op in enumerate(ops):
        node = p.op(op, node, id=f"op{i}")
    sink = ListSink()
    p.sink(sink, node, id="sink")
    tectum.run(p)
    return sink.packets


@pytest.mark.parametrize("copies", [False, True], ids=["slices", "copies"])
def test_runs_are_joined_up_to_the_least_span_below(copies: bool) -> None:
    ev = _stream()
    pieces = _pieces(ev, 1_000, copies)
    free = _Spans()
    _run([free], pieces)
    assert max(free.spans) > 30_000  # without a limit, runs span many pieces
    first, second = _Spans(10_000), _Spans(4_000)
    out = _run([first, second], pieces)
    assert_streams_equal([ev], out)
    assert max(first.spans) == 4_000 and max(second.spans) == 4_000  # the least of the two
    assert len(first.spans) < len(pieces) // 3  # joined still, four pieces a run


def test_a_span_shorter_than_a_packet_leaves_packets_whole() -> None:
    ev = _stream()
    pieces = _pieces(ev, 1_000, copies=False)
    op = _Spans(10)
    assert_streams_equal([ev], _run([op], pieces))
    assert op.spans == [q.t_end - q.t_start for q in pieces]
