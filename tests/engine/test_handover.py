"""What the engine does per output packet and per run, made cheaper
without losing what it guards: sample packets built by an operator with
``_trusted`` are real, immutable packets of their class that own their
fields' mapping; frames are counted by kind (plain ``str`` keys) on the way
out of an operator and into a sink; frames a source gives are still checked
where they enter; a plan's nodes by role are sorted once but handed out as
fresh lists."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import tectum
from tectum import EventPacket, FramePacket, Kind, Operator, PacketError, Pipeline, PosePacket, Source
from tectum.testing import ListSink, ListSource


def events(n_packets: int = 5, per: int = 40, span: int = 1000) -> list[EventPacket]:
    rng = np.random.default_rng(1)
    n = n_packets * per
    t = np.sort(rng.integers(0, n_packets * span, n)).astype(np.int64)
    ev = EventPacket(t, rng.integers(0, 16, n).astype(np.uint16), rng.integers(0, 12, n).astype(np.uint16),
                     np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8), sensor=(16, 12), t_start=0,
                     t_end=n_packets * span).validate()
    return [ev.slice_time(i * span, (i + 1) * span) for i in range(n_packets)]


class OneFrame(Operator):
    """Two frames per call, each a packet built trusted (as the repr operators do)."""

    name = "test.one_frame"
    consumes = (Kind.EVENTS,)
    produces = (Kind.FRAMES,)

    def process(self, packet: EventPacket) -> list[FramePacket]:
        image = np.zeros((1, 12, 16), np.int32)
        mid = (packet.t_start + packet.t_end) // 2
        return [FramePacket._trusted(np.array([t1 - 1], np.int64), {"images": image}, t0, t1)  # type: ignore[misc]
                for t0, t1 in ((packet.t_start, mid), (mid, packet.t_end))]

    def finish(self) -> list[FramePacket]:
        return []


@pytest.mark.parametrize("cls, data", [
    (FramePacket, {"images": np.zeros((2, 3, 4), np.uint8)}),
    (PosePacket, {"position": np.zeros((2, 3)), "orientation": np.tile([0.0, 0, 0, 1], (2, 1))}),
])
def test_trusted_sample_packet_is_its_class_immutable_and_owns_its_mapping(cls: Any, data: dict[str, Any]) -> None:
    t = np.array([3, 7], np.int64)
    given = dict(data)
    pkt = cls._trusted(t, given, np.int64(0), np.int64(10))
    assert type(pkt) is cls  # not the builder it was made with
    assert type(pkt.t_start) is int and type(pkt.t_end) is int and (pkt.t_start, pkt.t_end) == (0, 10)
    with pytest.raises(AttributeError, match="immutable"):
        pkt.t = t
    given[next(iter(data))] = np.ones(5)  # the caller's dict changes afterwards: the packet does not
    assert all(pkt.data[k] is v for k, v in data.items()) and set(pkt.data) == set(data)
    with pytest.raises(TypeError):
        pkt.data["extra"] = t  # type: ignore[index]
    built = cls(t, t_start=0, t_end=10, **data)
    assert pkt.validate() is pkt and repr(pkt) == repr(built)
    assert pkt.slice_time(0, 5).t.tolist() == [3] and type(pkt.slice_time(0, 5)) is cls


def test_frames_are_counted_by_kind_out_of_the_operator_and_into_the_sink() -> None:
    pieces = events()
    sink = ListSink()
    p = Pipeline()
    p.sink(sink, p.op(OneFrame(), p.source(ListSource(pieces), id="src"), id="op"), id="sink")
    stats = tectum.run(p)
    calls = stats.nodes["op"].packets_in
    assert calls >= 1 and [type(q) for q in sink.packets] == [FramePacket] * (2 * calls)
    for counts in (stats.nodes["op"].samples_out, stats.nodes["sink"].samples_in):
        assert counts == {"frames": 2 * calls}
        assert all(type(k) is str for k in counts)  # plain keys (reports, JSON), not Kind
    assert stats.nodes["op"].packets_out == stats.nodes["sink"].packets_in == 2 * calls
    assert stats.nodes["op"].events_in == sum(len(q) for q in pieces)


class BadFrames(Source):
    """A frame whose sample lies outside its interval, built unchecked."""

    name = "test.bad_frames"
    produces = (Kind.FRAMES,)

    def packets(self):  # type: ignore[no-untyped-def]
        yield FramePacket._trusted(np.array([50], np.int64), {"images": np.zeros((1, 2, 2))}, 0, 10)


def test_frames_a_source_gives_are_still_checked_where_they_enter() -> None:
    p = Pipeline()
    p.sink(ListSink(), p.source(BadFrames(), id="src"), id="sink")
    with pytest.raises(tectum.NodeError, match="src") as err:
        tectum.run(p)
    assert isinstance(err.value.__cause__, PacketError)


def test_nodes_by_role_are_fresh_lists_in_order() -> None:
    p = Pipeline()
    a = p.op(OneFrame(), p.source(ListSource(events()), id="src"), id="a")
    p.sink(ListSink(), a, id="s1")
    p.sink(ListSink(), a, id="s2")
    plan = p.validate()
    sinks = plan.of_role("sink")
    assert [n.id for n in sinks] == ["s1", "s2"] and [n.id for n in plan.of_role("source")] == ["src"]
    sinks.clear()
    assert [n.id for n in plan.of_role("sink")] == ["s1", "s2"]
    assert plan.of_role("operator")[0].id == "a"
