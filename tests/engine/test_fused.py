"""The fused push (engine/_fused.py) against the graph's general path.

Each pipeline runs twice, once as the scheduler builds it (fused where the
shape allows) and once with the fused push refused (``fused_push`` patched
to give None: the general ``Graph.push``); the two runs must write the same
packets in the same order, count the same (every stats field but time),
record the same latency runs and fail with the same error."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import numpy as np
import pytest

import tectum
import tectum._scheduler as scheduler
from tectum import EventPacket, FramePacket, Kind, Packet
from tectum._fused import fused_push
from tectum._stats import LatencyRecorder
from tectum.errors import NodeError
from tectum.testing import ListSink, ListSource


def _stream(n: int = 3000, t_end: int = 60_000) -> EventPacket:
    rng = np.random.default_rng(5)
    t = np.sort(rng.integers(0, t_end, n))
    return EventPacket.from_arrays(t, rng.integers(0, 32, n), rng.integers(0, 24, n), rng.choice([-1, 1], n),
                                   sensor=(32, 24), t_start=0, t_end=t_end).validate()


def _cuts(ev: EventPacket, us: int) -> list[EventPacket]:
    return [ev.slice_time(a, a + us) for a in range(ev.t_start, ev.t_end, us)]


class _Frames(tectum.Operator):
    """Per packet: a frame of its event count, then its events with ``x``
    even; ``finish`` gives a last frame (outputs of two kinds, a flush).
    Runs of slices are joined up to 2 ms (many calls a run)."""

    name = "filter.frames_fused_test"

    def join_us(self) -> int:
        return 2000

    def __init__(self, fail_at: int = -1) -> None:
        self.calls = 0
        self.fail_at = fail_at

    def process(self, packet: EventPacket) -> list[Packet]:
        self.calls += 1
        if self.calls == self.fail_at:
            raise ValueError(f"bad packet {self.calls}")
        frame = FramePacket([packet.t_end - 1], images=np.full((1, 2, 2), len(packet), np.int32),
                            t_start=packet.t_start, t_end=packet.t_end)
        return [frame, packet.select(packet.x % 2 == 0)]

    def finish(self) -> list[Packet]:
        return [FramePacket([10**9], images=np.full((1, 2, 2), -self.calls, np.int32), t_start=10**9,
                            t_end=10**9 + 1)]


class _Odd(tectum.Operator):
    """Events with ``y`` odd, as one packet, a generator or None (the ways an
    operator may return), by call number."""

    name = "filter.odd_fused_test"

    def join_us(self) -> int:
        return 2000

    def __init__(self) -> None:
        self.calls = 0

    def process(self, packet: EventPacket) -> Any:
        self.calls += 1
        out = packet.select(packet.y % 2 == 1)
        if self.calls % 3 == 0:
            return out
        if self.calls % 3 == 1:
            return (q for q in [out])
        return None if not len(out) else [out]


class _Ticks(_Odd):
    name = "filter.ticks_fused_test"

    def on_tick(self, t_us: int) -> list[Packet]:
        return []


class _Journal(ListSink):
    """A list sink that journals its calls (order of writes and the close)
    into a shared list, and fails on its ``fail_at``-th write."""

    def __init__(self, journal: list[str], tag: str, fail_at: int = -1) -> None:
        super().__init__()
        self.journal, self.tag, self.fail_at = journal, tag, fail_at

    def write(self, packet: Packet) -> None:
        if len(self.packets) + 1 == self.fail_at:
            raise OSError(f"disk full at {self.fail_at}")
        self.journal.append(f"{self.tag} {packet.kind} {packet.t_start}")
        super().write(packet)

    def close(self) -> None:
        self.journal.append(f"{self.tag} close")
        super().close()

    def abort(self) -> None:
        self.journal.append(f"{self.tag} abort")
        super().abort()


Build = Callable[[list[str]], tectum.Pipeline]


def _run(build: Build, fused: bool, monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """Run ``build``'s pipeline with the fused push allowed or refused:
    what happened (journal, latency runs by sink, stats without times, the
    error's text and node, whether a fused push was made)."""
    journal: list[str] = []
    runs: list[tuple[int, int]] = []
    made: list[bool] = []
    plain_add = LatencyRecorder.add

    def add(self: LatencyRecorder, seconds: float, count: int = 1) -> None:
        runs.append((id(self), count))
        plain_add(self, seconds, count)

    def spy(graph: Any, node_id: str) -> Any:
        push = fused_push(graph, node_id) if fused else None
        made.append(push is not None)
        return push

    monkeypatch.setattr(LatencyRecorder, "add", add)
    monkeypatch.setattr(scheduler, "fused_push", spy)
    p = build(journal)
    error = None
    stats = None
    try:
        stats = tectum.run(p)
    except NodeError as e:
        error = (str(e), e.node)
    monkeypatch.undo()
    result: dict[str, Any] = {"journal": journal, "error": error, "made": made}
    if stats is not None:
        result["nodes"] = {nid: {k: v for k, v in asdict(s).items() if k != "busy_ns"}
                           for nid, s in stats.nodes.items()}
        lat = {id(r): sid for sid, r in stats.latency.items()}
        result["runs"] = [(lat.get(i), n) for i, n in runs]
        result["latency"] = {sid: r.count for sid, r in stats.latency.items()}
    return result


def _both(build: Build, monkeypatch: pytest.MonkeyPatch) -> tuple[dict[str, Any], dict[str, Any]]:
    return _run(build, True, monkeypatch), _run(build, False, monkeypatch)


def _one_op(op: Callable[[], tectum.Operator], us: int = 1000, **sink: Any) -> Build:
    ev = _stream()

    def build(journal: list[str]) -> tectum.Pipeline:
        p = tectum.Pipeline()
        src = p.source(ListSource(_cuts(ev, us)), id="src")
        p.sink(_Journal(journal, "sink", **sink), p.op(op(), src, id="op"), id="sink")
        return p
    return build


def _chain(*ops: Callable[[], tectum.Operator], us: int = 1000) -> Build:
    ev = _stream()

    def build(journal: list[str]) -> tectum.Pipeline:
        p = tectum.Pipeline()
        up = p.source(ListSource(_cuts(ev, us)), id="src")
        for i, op in enumerate(ops):
            up = p.op(op(), up, id=f"op{i}")
        p.sink(_Journal(journal, "sink"), up, id="sink")
        return p
    return build


@pytest.mark.parametrize("us", [300, 1000, 20_000])
def test_one_operator_fused_writes_and_counts_as_the_general_path(us: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two kinds out per call and a flush at the end, slices of several
    sizes (joined or not): the same writes in the same order, the same
    counts of every node, the same latency runs."""
    fused, plain = _both(_one_op(_Frames, us), monkeypatch)
    assert fused["made"] == [True] and plain["made"] == [False]
    assert fused["journal"] == plain["journal"] and fused["journal"][-1] == "sink close"
    assert fused["nodes"] == plain["nodes"] and fused["runs"] == plain["runs"]
    assert fused["nodes"]["sink"]["samples_in"] == {"frames": fused["nodes"]["op"]["samples_out"]["frames"]} != {}
    assert fused["latency"]["sink"] == fused["nodes"]["sink"]["packets_in"] > 0


def test_a_chain_fused_handles_every_return_and_kinds_passing_by(monkeypatch: pytest.MonkeyPatch) -> None:
    """A chain of three: frames from the first pass by the events-only
    operators below it (the graph's own path), which return a packet, a
    generator, None or a list; the same writes, counts and runs."""
    fused, plain = _both(_chain(_Frames, _Odd, _Odd), monkeypatch)
    assert fused["made"] == [True]
    assert fused["journal"] == plain["journal"] and fused["nodes"] == plain["nodes"] and fused["runs"] == plain["runs"]
    assert any(" frames " in j for j in fused["journal"]) and any(" events " in j for j in fused["journal"])


def test_an_operator_error_names_the_node_and_aborts_the_sink_alike(monkeypatch: pytest.MonkeyPatch) -> None:
    fused, plain = _both(_chain(lambda: _Frames(fail_at=7), _Odd), monkeypatch)
    assert fused["made"] == [True]
    assert fused["error"] == plain["error"] and fused["error"][1] == "op0" and "bad packet 7" in fused["error"][0]
    assert fused["journal"] == plain["journal"] and fused["journal"][-1] == "sink abort"


def test_a_sink_error_names_the_sink_alike(monkeypatch: pytest.MonkeyPatch) -> None:
    fused, plain = _both(_one_op(_Frames, fail_at=5), monkeypatch)
    assert fused["made"] == [True]
    assert fused["error"] == plain["error"] and fused["error"][1] == "sink" and "disk full at 5" in fused["error"][0]
    assert fused["journal"] == plain["journal"] and len(fused["journal"]) == 5  # 4 writes, the abort


def _fan_out(journal: list[str]) -> tectum.Pipeline:
    p = tectum.Pipeline()
    op = p.op(_Frames(), p.source(ListSource(_cuts(_stream(), 1000)), id="src"), id="op")
    p.sink(_Journal(journal, "a"), op, id="a")
    p.sink(_Journal(journal, "b"), op, id="b")
    return p


def _ticks(journal: list[str]) -> tectum.Pipeline:
    p = tectum.Pipeline()
    p.sink(_Journal(journal, "sink"), p.op(_Ticks(), p.source(ListSource(_cuts(_stream(), 1000)))))
    return p


def _dropping(journal: list[str]) -> tectum.Pipeline:
    p = tectum.Pipeline()
    p.sink(_Journal(journal, "sink"), p.op(_Frames(), p.source(ListSource(_cuts(_stream(), 1000)))),
           policy="keep_latest", buffer=1_000_000)
    return p


def _offloaded(journal: list[str]) -> tectum.Pipeline:
    p = tectum.Pipeline()
    p.sink(_Journal(journal, "sink"), p.op(_Frames(), p.source(ListSource(_cuts(_stream(), 1000))), offload=True))
    return p


@pytest.mark.parametrize("build", [_fan_out, _ticks, _dropping, _offloaded], ids=lambda b: b.__name__)
def test_other_shapes_take_the_general_path(build: Build, monkeypatch: pytest.MonkeyPatch) -> None:
    """Fan-out, an operator with ticks, a sink behind an edge that drops,
    an offloaded operator: no fused push is made, and the runs with and
    without it allowed are the same."""
    fused, plain = _both(build, monkeypatch)
    assert fused["made"] == [False] and fused["journal"] == plain["journal"] and fused["nodes"] == plain["nodes"]


def test_the_fused_push_is_the_general_push_on_a_graph(monkeypatch: pytest.MonkeyPatch) -> None:
    """Driven by hand on one graph shape (source, operator, sink written
    inline): an events packet and a frame packet pushed at the source give
    the same writes and counts through the fused push as through
    ``Graph.push`` on a twin graph."""
    from tectum._graph import Graph
    from tectum._stats import Stats

    ev = _stream()
    got = {}
    for way in ("fused", "plain"):
        p = tectum.Pipeline()
        src = p.source(ListSource([ev]), id="src")
        p.sink(ListSink(), p.op(_Odd(), src, id="op"), id="sink")
        plan = p.validate()
        stats = Stats()
        graph = Graph(plan, stats=stats)
        out = scheduler._Outbox({})
        sink = plan.nodes["sink"].instantiate()
        out.write_inline(graph, {"sink": sink}, stats, lambda: 0.0)
        push = fused_push(graph, "src") if way == "fused" else graph.push
        assert push is not None
        frame = FramePacket([5], images=np.zeros((1, 2, 2)), t_start=0, t_end=10)
        delivered = [push("src", q) for q in (*_cuts(ev, 10_000), frame)]
        got[way] = (delivered, [(q.kind, q.t_start, len(q)) for q in sink.packets],  # type: ignore[attr-defined]
                    {n: {k: v for k, v in asdict(s).items() if k != "busy_ns"} for n, s in stats.nodes.items()})
    assert got["fused"] == got["plain"]
    assert got["fused"][2]["op"]["samples_in"] == {}  # the frame went the graph's own way: passes by
    assert got["fused"][2]["sink"]["samples_in"] == {"frames": 1} and Kind.FRAMES in {k for k, *_ in got["fused"][1]}
