"""Delayed edges and feedback loops.

A two-node loop of tiny operators: ``Acc`` counts events and adds what
comes back on its ``fb`` port; ``Echo`` returns some of Acc's running totals,
which reach Acc again ``DELAY`` µs later. The totals equal a hand-computed
reference (a plain loop over the events), whatever the packet splits and
``max_events``, under ``tectum.run`` (inline and offloaded, bounded edges of
one packet), :class:`tectum.Stepper` and :class:`tectum.ThreadedPipeline`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest
import trio

import tectum
from tectum import EventPacket, Kind, Operator, Packet, PipelineError, Port, TriggerPacket
from tectum.testing import ListSink, ListSource, split_stream

DELAY = 700  # µs


def _triggers(t: np.ndarray, value: np.ndarray, t0: int, t1: int, channel: int) -> TriggerPacket:
    return TriggerPacket(t, channel=np.full(len(t), channel, np.int64), value=value.astype(np.int64),
                         t_start=t0, t_end=t1)


class Acc(Operator):
    """Running total: +1 per event, + the value of each sample on ``fb``
    (samples before events of the same µs); one output sample per event."""

    name = "test.acc"
    inputs = {"events": Port(Kind.EVENTS), "fb": Port(Kind.TRIGGERS, required=False)}
    produces = (Kind.TRIGGERS,)

    def __init__(self) -> None:
        self.total = 0

    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        ev, fb = ports.get("events"), ports.get("fb")
        some = ev if ev is not None else fb
        assert some is not None
        t0, t1 = some.t_start, some.t_end
        ft = fb.t if fb is not None else np.empty(0, np.int64)
        fv = fb.value if fb is not None else np.empty(0, np.int64)  # type: ignore[attr-defined]
        et = ev.t if ev is not None else np.empty(0, np.int64)
        out = np.empty(len(et), np.int64)
        j = 0
        for i, t in enumerate(et):
            while j < len(ft) and ft[j] <= t:
                self.total += int(fv[j])
                j += 1
            self.total += 1
            out[i] = self.total
        self.total += int(fv[j:].sum())
        return [_triggers(et.copy(), out, t0, t1, 0)]


class Echo(Operator):
    """Returns ``total % 7`` for each total divisible by ``every``, at its
    time; emits nothing at all for a batch without one (the loop then moves
    on by the operator's output mark alone)."""

    name = "test.echo"
    inputs = {"acc": Port(Kind.TRIGGERS)}
    produces = (Kind.TRIGGERS,)

    def __init__(self, every: int = 3) -> None:
        self.every = every

    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        acc = ports.get("acc")
        if acc is None:
            return []
        v = acc.value  # type: ignore[attr-defined]
        keep = v % self.every == 0
        if not keep.any():
            return []
        return [_triggers(acc.t[keep], v[keep] % 7, acc.t_start, acc.t_end, 1)]


class LagEcho(Echo):
    """Echo whose outputs come ``lag_us`` late: a sample at ``t`` leaves
    once the input has passed ``t + lag_us`` (stamped ``t``), as a map
    stamped with its last event does; says so through ``output_mark``."""

    def __init__(self, lag_us: int) -> None:
        super().__init__()
        self.lag = lag_us
        self.held: list[TriggerPacket] = []
        self.mark: int | None = None  # nothing more will be emitted before this

    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        got = super().process_ports(ports)
        acc = ports.get("acc")
        self.held += got  # type: ignore[arg-type]
        return self._release(acc.t_end - self.lag) if acc is not None else []

    def _release(self, upto: int) -> list[Packet]:
        if not self.held:
            return []
        start = self.mark if self.mark is not None else self.held[0].t_start
        if upto <= start:
            return []
        t = np.concatenate([q.t for q in self.held])
        v = np.concatenate([q.value for q in self.held])
        n = int(np.searchsorted(t, upto))
        self.held = [_triggers(t[n:], v[n:], upto, max(upto, int(t[-1]) + 1), 1)] if n < len(t) else []
        self.mark = upto
        return [_triggers(t[:n], v[:n], start, upto, 1)]

    def output_mark(self, watermark: int) -> int:
        mark = min([watermark - self.lag, *(int(q.t[0]) for q in self.held if len(q))])
        self.mark = max(mark, self.mark if self.mark is not None else mark)
        return self.mark

    def finish(self) -> list[Packet]:
        return self._release(2**62)


def reference(t: np.ndarray, delay: int = DELAY, every: int = 3) -> np.ndarray:
    """Acc's totals by hand: the i-th event's total is i plus every echo
    (total % 7 of an earlier total divisible by ``every``) due by its time."""
    totals: list[int] = []
    for i, ti in enumerate(t):
        back = sum(a % 7 for a, tj in zip(totals, t) if a % every == 0 and tj + delay <= ti)
        totals.append(i + 1 + back)
    return np.array(totals, np.int64)


def _events(n: int = 300, seed: int = 0) -> EventPacket:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(100, 20_000, n))
    xy = rng.integers(0, 16, n)
    return EventPacket.from_arrays(t, xy, xy, np.ones(n), sensor=(16, 16), t_start=100, t_end=20_000)


def _loop(pieces: list[Packet], *, offload: bool = False, buffer: int = 64, echo: Operator | None = None,
          delay: int = DELAY, max_events: int = 65536) -> tuple[tectum.Pipeline, ListSink]:
    p = tectum.Pipeline(max_events=max_events)
    cam = p.source(ListSource(pieces), id="cam")
    p.op(Acc(), events=cam, fb=p.delayed("echo", delay), id="acc", offload=offload, buffer=buffer)
    p.op(echo or Echo(), acc="acc", id="echo", offload=offload, buffer=buffer)
    sink = ListSink()
    p.sink(sink, "acc", buffer=buffer)
    return p, sink


def _totals(sink: ListSink) -> np.ndarray:
    pk = [q for q in sink.packets if q.kind == Kind.TRIGGERS]
    return np.concatenate([q.value for q in pk]) if pk else np.empty(0, np.int64)  # type: ignore[attr-defined]


def _run(p: tectum.Pipeline, runner: str, pieces: list[Packet]) -> None:
    if runner == "run":
        async def main() -> None:
            with trio.fail_after(60):  # a deadlock fails, it does not hang
                await tectum.arun(p)
        trio.run(main)
    elif runner == "stepper":
        with tectum.Stepper(p) as st:
            for q in pieces:
                st.push(q)
            st.end()
    else:
        tectum.ThreadedPipeline(p, watch=["acc"]).start().join(60)


@pytest.mark.parametrize("runner", ["run", "run-offloaded", "stepper", "threaded"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_loop_equals_the_hand_computed_reference(runner: str, seed: int) -> None:
    ev = _events(seed=seed)
    every = (3, 41, 3)[seed]  # 41: Echo rarely emits, the loop moves on by output marks
    expected = reference(ev.t, every=every)
    assert expected[-1] > len(ev) + 20  # the echoes matter
    rng = np.random.default_rng(seed)
    cuts = rng.integers(0, len(ev), size=int(rng.integers(0, 40))).tolist()
    ticks = rng.integers(ev.t_start, ev.t_end, size=5).tolist()
    pieces = split_stream(ev, cuts, ticks)
    offload = runner == "run-offloaded"
    p, sink = _loop(pieces, offload=offload, buffer=1 if offload else 64, echo=Echo(every),
                    max_events=int(rng.choice([1, 7, 65536])))
    _run(p, runner.split("-")[0], pieces)
    assert sink.closed and not sink.aborted
    np.testing.assert_array_equal(_totals(sink), expected)


def test_a_lagging_operator_states_its_lag_and_the_loop_still_runs() -> None:
    ev = _events()
    pieces = split_stream(ev, list(range(0, len(ev), 17)))
    p, sink = _loop(pieces, echo=LagEcho(DELAY // 2))
    tectum.run(p)
    np.testing.assert_array_equal(_totals(sink), reference(ev.t))


@pytest.mark.parametrize("runner", ["run", "run-offloaded", "stepper", "threaded"])
def test_a_loop_that_stalls_runs_on_without_its_feedback(runner: str, caplog: Any) -> None:
    """Echo's lag (3 x the delay) stalls the loop; at the end of input the
    feedback port ends and Acc counts the rest of the events alone, the
    same under every runner and split."""
    ev = _events()
    stall_free = reference(ev.t)
    results = []
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        pieces = split_stream(ev, rng.integers(0, len(ev), 20).tolist())
        p, sink = _loop(pieces, echo=LagEcho(3 * DELAY), offload=runner == "run-offloaded")
        with caplog.at_level("WARNING", logger="tectum"):
            _run(p, runner.split("-")[0], pieces)
        assert "feedback loop acc -> echo stalled: node 'acc' has its other inputs up to 20000 µs, port 'fb' at" \
            in caplog.text
        results.append(_totals(sink))
    np.testing.assert_array_equal(results[0], results[1])
    got = results[0]
    assert len(got) == len(ev) and np.all(np.diff(got) >= 1)  # every event counted
    stop = int(np.searchsorted(ev.t, 100 + DELAY))  # nothing came back before the first delay
    np.testing.assert_array_equal(got[:stop], stall_free[:stop])
    assert got[-1] < stall_free[-1]  # what the loop did not bring back is missing


def test_offloaded_loop_with_one_packet_edges_does_not_deadlock() -> None:
    ev = _events(n=2000, seed=5)
    pieces = list(ev.batches(3))
    p, sink = _loop(pieces, offload=True, buffer=1, max_events=1)
    _run(p, "run", pieces)
    np.testing.assert_array_equal(_totals(sink), reference(ev.t))


class Record(Operator):
    """Hands on what its ``trig`` port brings (to see a delayed edge's effect)."""

    name = "test.record"
    inputs = {"events": Port(Kind.EVENTS), "trig": Port(Kind.TRIGGERS)}
    produces = (Kind.TRIGGERS,)

    def process_ports(self, ports: Mapping[str, Packet]) -> list[Packet]:
        q = ports.get("trig")
        return [q] if q is not None else []


def test_a_delayed_edge_shifts_samples_and_starts_late() -> None:
    """Samples arrive ``delay`` later; what would arrive before the node's
    other input's start + delay is dropped (the port starts empty)."""
    ev = _events()
    t = np.array([50, 100, 500, 900, 5_000, 19_000], np.int64)
    trig = _triggers(t, np.arange(6), 50, 20_000, 2)
    for order in ("trig first", "events first"):
        p = tectum.Pipeline()
        cam = p.source(ListSource([ev]), id="cam")
        tr = p.source(ListSource([trig]), id="tr")
        p.op(Record(), events=cam, trig=p.delayed(tr, 1_000), id="rec")
        sink = ListSink()
        p.sink(sink, "rec")
        with tectum.Stepper(p) as st:
            for src in (("tr", "cam") if order == "trig first" else ("cam", "tr")):
                st.push(ev if src == "cam" else trig, into=src)
            st.end("cam")
            st.end("tr")
        got = np.concatenate([q.t for q in sink.packets])
        np.testing.assert_array_equal(got, [1_100, 1_500, 1_900, 6_000, 20_000], err_msg=order)


def test_delayed_edges_from_a_file(tmp_path: Any) -> None:
    f = tmp_path / "loop.toml"
    f.write_text('[[source]]\nid = "cam"\nuri = "pattern:"\nparams = { duration_us = 5000 }\n'
                 '[[op]]\nid = "a"\nname = "map.emvs"\n'
                 'input = { events = "cam", poses = { from = "b", delay_us = 2000 } }\n'
                 '[[op]]\nid = "b"\nname = "tracker.angular_velocity"\ninput = "a"\n')
    p = tectum.Pipeline.from_toml(f)
    assert p["a"].ports["poses"] == "b" and p["a"].delays == {"poses": 2000}
    f.write_text('[[source]]\nid = "cam"\nuri = "pattern:"\n[[op]]\nid = "a"\nname = "map.emvs"\ninput = "cam"\n'
                 'ports = { poses = { from = "b", delay_us = 300 } }\n')
    p = tectum.Pipeline.from_toml(f)
    assert p["a"].inputs == ("cam",) and p["a"].ports["poses"] == "b" and p["a"].delays == {"poses": 300}
    f.write_text('[[source]]\nid = "cam"\nuri = "pattern:"\n[[op]]\nid = "a"\nname = "map.emvs"\n'
                 'input = { events = "cam", poses = { from = "b", delay = 2000 } }\n')
    with pytest.raises(PipelineError, match=r"\(\'a\'\): port 'poses': a delayed input is"):
        tectum.Pipeline.from_toml(f)


def _bare(acc_fb: Any) -> tectum.Pipeline:
    p = tectum.Pipeline()
    cam = p.source(ListSource([_events()]), id="cam")
    p.op(Acc(), events=cam, fb=acc_fb, id="acc")
    p.op(Echo(), acc="acc", id="echo")
    return p


def test_a_cycle_without_a_delay_is_refused_naming_it() -> None:
    with pytest.raises(PipelineError, match=r"cycle: (acc -> echo -> acc|echo -> acc -> echo); a loop needs a "
                                            r"delayed edge"):
        _bare("echo").validate()
    plan = _bare(tectum.Pipeline.delayed("echo", 5)).validate()
    assert plan.loops == (("acc", "echo"),) and plan.nodes["acc"].feedback == {"fb"}


@pytest.mark.parametrize("delay", [0, -5, 2.5])
def test_a_delay_must_be_a_positive_integer(delay: Any) -> None:
    with pytest.raises(PipelineError, match=r"delayed edge from 'echo': delay_us must be an integer > 0"):
        _bare(tectum.Pipeline.delayed("echo", delay))


def test_misplaced_delays_are_refused() -> None:
    p = tectum.Pipeline()
    cam = p.source(ListSource([_events()]), id="cam")
    with pytest.raises(PipelineError, match="goes into a named port"):
        p.op("filter.refractory", [p.delayed(cam, 10)])  # type: ignore[list-item]
    p.op(Record(), events=p.delayed(cam, 10), trig=p.delayed(cam, 10), id="r")
    with pytest.raises(PipelineError, match="every input is delayed"):
        p.validate()
    q = tectum.Pipeline()
    cam = q.source(ListSource([_events()]), id="cam")
    q.op(Acc(), events=cam, fb=q.delayed("f", 10), id="acc")
    q.op("filter.refractory", "acc", id="f")
    with pytest.raises(PipelineError, match=r"node 'f' \(filter.refractory\) is on the loop acc -> f: nodes on a "
                                            r"loop take their inputs on named ports"):
        q.validate()


def test_time_shards_refuse_a_loop() -> None:
    from tectum.scale import NotShardable, warmup_of

    with pytest.raises(NotShardable, match=r"feedback loop acc -> echo"):
        warmup_of(_bare(tectum.Pipeline.delayed("echo", 5)).validate())


def test_a_delayed_edge_travels_to_a_worker() -> None:
    """The dict a shard's worker rebuilds the pipeline from keeps the delay."""
    from tectum.scale import pipeline_dict

    p = tectum.Pipeline()
    cam = p.source("pattern:", id="cam")
    p.op("map.emvs", events=cam, poses=p.delayed("gt", 1500), id="m")
    p.source("pattern:", id="gt")
    d = pipeline_dict(p)
    assert d["op"][0]["input"]["poses"] == {"from": "gt", "delay_us": 1500}
    back = tectum.Pipeline.from_dict(d)["m"]
    assert back.delays == {"poses": 1500} and back.ports["poses"] == "gt"
