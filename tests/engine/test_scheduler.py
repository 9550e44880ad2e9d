"""The trio scheduler: lossless runs, policies, pacing, errors, shutdown."""

from __future__ import annotations

import numpy as np
import pytest
import trio
import trio.testing

import tectum
from tectum import EventPacket, NodeError, Operator, PacketError, Pipeline, Sink
from tectum.plugins.filter import Refractory
from tectum.testing import ListSink, ListSource, assert_streams_equal, feed

from helpers import bars


def chain(stream, sink, **batch):
    p = Pipeline(**batch)
    s = p.source(ListSource([stream]), id="src")
    o = p.op("filter.refractory", s, id="rf", period_us=300)
    p.sink(sink, o, id="out")
    return p


@pytest.mark.parametrize("max_events", [1, 7, 100_000])
def test_output_does_not_depend_on_batch_size(small_stream, max_events):
    sink = ListSink()
    stats = tectum.run(chain(small_stream, sink, max_events=max_events))
    assert_streams_equal(feed(Refractory(300), [small_stream]), sink.packets)
    assert sink.closed and not sink.aborted
    assert stats.nodes["src"].events_out == len(small_stream)
    assert stats.nodes["rf"].events_in == len(small_stream)
    if max_events == 1:  # event by event: one timestamp per packet
        assert stats.nodes["rf"].packets_in == len(np.unique(small_stream.t))
    assert stats.latency["out"].count == stats.nodes["out"].packets_in


class Boom(Operator):
    name = "filter.boom_test"

    def __init__(self, after: int = 2) -> None:
        self.left = after

    def process(self, packet):
        self.left -= 1
        if self.left < 0:
            raise RuntimeError("kaboom")
        return [packet]


def test_an_error_names_the_node_and_aborts_sinks(small_stream, tmp_path):
    sink = ListSink()
    out = tmp_path / "out.npz"
    p = Pipeline(max_events=50)
    s = p.source(ListSource([small_stream]), id="src")
    b = p.op(Boom(), s, id="boom")
    p.sink(sink, b, id="mem")
    p.sink(str(out), b, id="file")
    with pytest.raises(NodeError, match="node 'boom' failed: RuntimeError: kaboom") as ei:
        tectum.run(p)
    assert ei.value.node == "boom" and isinstance(ei.value.__cause__, RuntimeError)
    assert sink.aborted and not sink.closed
    assert not out.exists() and list(tmp_path.iterdir()) == []  # nothing half-written


def test_bad_packets_are_stopped_at_the_source():
    bad = EventPacket.from_arrays([5, 3], [0, 1], [0, 0], [1, 1], sensor=(4, 4), validate=False, t_start=0, t_end=9)
    p = Pipeline()
    p.sink(ListSink(), p.source(ListSource([bad]), id="cam"))
    with pytest.raises(NodeError, match="node 'cam' failed: PacketError: source 'cam': timestamps decrease at index 1") as ei:
        tectum.run(p)
    assert isinstance(ei.value.__cause__, PacketError)


def test_repair_resorts_within_the_window_and_counts():
    t = np.array([10, 30, 20, 40, 5, 50])  # 20 is 10 µs late (fixable), 5 is too late
    x = np.array([0, 1, 2, 9, 0, 1])  # x=9 is outside the 4x4 sensor
    a = EventPacket.from_arrays(t[:3], x[:3], [0] * 3, [1] * 3, sensor=(4, 4), validate=False, t_start=0, t_end=31)
    b = EventPacket.from_arrays(t[3:], x[3:], [0] * 3, [1] * 3, sensor=(4, 4), validate=False, t_start=31, t_end=51)
    sink = ListSink()
    p = Pipeline()
    p.sink(sink, p.source(ListSource([a, b]), id="cam", repair=15))
    stats = tectum.run(p)
    assert sink.events().t.tolist() == [10, 20, 30, 50]
    assert stats.nodes["cam"].repairs == {"out_of_bounds": 1, "bad_polarity": 0, "reordered": 1, "late": 1}


def test_fan_out_and_merge_by_timestamp():
    a, b = bars(seed=1, noise_hz=5.0), bars(seed=2, speed=300.0)
    sink, side = ListSink(), ListSink()
    p = Pipeline(max_events=64)
    sa = p.source(ListSource([a]), id="a")
    sb = p.source(ListSource([b]), id="b")
    m = p.op("filter.refractory", [sa, sb], id="merged", period_us=0)
    p.sink(sink, m)
    p.sink(side, sa)  # fan-out: a feeds both the merge and this sink
    tectum.run(p)
    got = sink.events()
    assert len(got) == len(a) + len(b)
    assert np.all(np.diff(got.t) >= 0)
    want = np.sort(np.concatenate([a.t, b.t]), kind="stable")
    assert np.array_equal(got.t, want)
    assert_streams_equal([a], side.packets)


class SlowSink(Sink):
    """A sink that takes 10 ms (of trio time) per packet."""

    name = "slow"

    def __init__(self) -> None:
        self.got = []

    async def awrite(self, packet):
        await trio.sleep(0.01)
        self.got.append(packet)


@pytest.mark.parametrize("policy", ["block", "keep_latest", "drop"])
def test_edge_policies(small_stream, policy):
    sink = SlowSink()
    p = Pipeline(max_events=10)
    p.sink(sink, p.source(ListSource([small_stream]), id="src"), id="slow", policy=policy, buffer=2)
    stats = trio.run(tectum.arun, p, clock=trio.testing.MockClock(autojump_threshold=0))
    sent = stats.nodes["src"].packets_out
    drops = stats.nodes["slow"].drops
    assert len(sink.got) + drops == sent
    if policy == "block":
        assert drops == 0
        assert_streams_equal([small_stream], sink.got)
    else:
        assert drops > 0
        if policy == "keep_latest":  # the newest packet always arrives
            assert sink.got[-1].t_end == small_stream.t_end


def test_pacing_follows_the_clock_and_batches_grow_only_under_load(small_stream):
    async def main():
        sink = ListSink()
        p = Pipeline(pace=1.0)
        p.sink(sink, p.source(ListSource([small_stream]), id="src"), id="out")
        t0 = trio.current_time()
        stats = await tectum.arun(p)
        return sink, stats, trio.current_time() - t0

    sink, stats, elapsed = trio.run(main, clock=trio.testing.MockClock(autojump_threshold=0))
    assert elapsed == pytest.approx((small_stream.t_end - small_stream.t_start - 1) / 1e6, abs=2e-6)
    # light load (instant processing on the mock clock): one timestamp per packet
    assert all(len(np.unique(q.t)) <= 1 for q in sink.packets)
    assert_streams_equal([small_stream], sink.packets)
    assert stats.latency["out"].percentiles()["max"] < 1.0  # µs: nothing queued


def test_pacing_in_windows(small_stream):
    sink = ListSink()
    p = Pipeline(pace=2.0, max_latency_us=5000)
    p.sink(sink, p.source(ListSource([small_stream]), id="src"))
    trio.run(tectum.arun, p, clock=trio.testing.MockClock(autojump_threshold=0))
    starts = [q.t_start for q in sink.packets]
    assert all(s % 5000 == 0 for s in starts)
    assert_streams_equal([small_stream], sink.packets)


async def test_open_pipeline_taps_and_cancel(small_stream):
    p = Pipeline(max_events=20)
    s = p.source(ListSource([small_stream] * 1), id="src")
    rf = p.op("filter.refractory", s, id="rf", period_us=300)
    sink = ListSink()
    p.sink(sink, rf)
    got = []
    async with tectum.open_pipeline(p, taps=["rf"]) as run:
        async for pkt in run.outputs("rf"):
            got.append(pkt)
    assert_streams_equal(got, sink.packets)
    assert sink.closed

    class Endless(tectum.Source):
        name = "endless"

        async def apackets(self):
            t = 0
            while True:
                await trio.sleep(0.001)
                yield EventPacket.empty((4, 4), t, t + 1000)
                t += 1000

    p2 = Pipeline()
    sink2 = ListSink()
    p2.sink(sink2, p2.source(Endless()))
    with trio.fail_after(30):
        async with tectum.open_pipeline(p2) as run:
            while len(sink2.packets) <= 3:  # wait for data, not for a time (CI machines are loaded)
                await trio.sleep(0.001)
            run.cancel()
    assert sink2.closed and not sink2.aborted and len(sink2.packets) > 3


class Logged(Operator):
    """Passes packets on, noting each call in a shared log."""

    name = "filter.logged_test"

    def __init__(self, log: list) -> None:
        self.log = log

    def process(self, packet):
        self.log.append("op")
        return [packet]


class LoggedSink(ListSink):
    def __init__(self, log: list, fail_at: int | None = None) -> None:
        super().__init__()
        self.log = log
        self.fail_at = fail_at

    def write(self, packet):
        if len(self.packets) == self.fail_at:
            raise OSError("disk full")
        self.log.append("sink")
        super().write(packet)


def test_a_plain_lossless_sink_is_written_as_each_packet_is_made(small_stream):
    # a sink with a plain write and the block policy is written by the task that made
    # the packet, at once: each output is written (and can be freed) before the next is made
    log: list = []
    sink = LoggedSink(log)
    p = Pipeline(max_events=50)
    p.sink(sink, p.op(Logged(log), p.source(ListSource([small_stream]), id="src")), id="out")
    stats = tectum.run(p)
    n = stats.nodes["out"].packets_in
    assert n > 10 and log == ["op", "sink"] * n
    assert_streams_equal([small_stream], sink.packets)
    assert stats.latency["out"].count == n
    assert stats.nodes["out"].events_in == len(small_stream)


def test_a_failing_inline_sink_is_named_and_the_others_abort(small_stream, tmp_path):
    bad, good = LoggedSink([], fail_at=3), ListSink()
    out = tmp_path / "out.npz"
    p = Pipeline(max_events=50)
    s = p.source(ListSource([small_stream]), id="src")
    p.sink(bad, s, id="bad")
    p.sink(good, s, id="good")
    p.sink(str(out), s, id="file")
    with pytest.raises(NodeError, match="node 'bad' failed: OSError: disk full"):
        tectum.run(p)
    assert good.aborted and not good.closed
    assert list(tmp_path.iterdir()) == []


class TrioSink(ListSink):
    """Notes whether each write runs inside trio."""

    def __init__(self) -> None:
        super().__init__()
        self.in_trio: list[bool] = []

    def write(self, packet):
        try:
            trio.lowlevel.current_task()
            self.in_trio.append(True)
        except RuntimeError:
            self.in_trio.append(False)
        super().write(packet)


@pytest.mark.parametrize("how", ["plain", "keep_latest", "two sources", "paced"])
def test_run_starts_trio_only_where_something_runs_concurrently(small_stream, how):
    sink = TrioSink()
    p = Pipeline(max_events=100, pace=1000.0 if how == "paced" else None)
    s = p.source(ListSource([small_stream]), id="src")
    if how == "two sources":
        p.sink(ListSink(), p.source(ListSource([small_stream]), id="other"))
    o = p.op("filter.refractory", s, id="rf", period_us=300)
    p.sink(sink, o, id="out", policy="keep_latest" if how == "keep_latest" else "block",
           buffer=100_000 if how == "keep_latest" else 64)
    stats = tectum.run(p)
    assert sink.in_trio and set(sink.in_trio) == {how != "plain"}
    assert_streams_equal(feed(Refractory(300), [small_stream]), sink.packets)
    assert sink.closed and not sink.aborted
    assert stats.nodes["out"].events_in == stats.nodes["rf"].events_out
    assert stats.latency["out"].count == stats.nodes["out"].packets_in
    assert stats.wall_s > 0


class Interrupt(Operator):
    name = "filter.interrupt_test"

    def process(self, packet):
        if len(packet) > 100:  # not in warmup()
            raise KeyboardInterrupt
        return [packet]


def test_an_interrupt_aborts_the_sinks_without_trio_too(small_stream, tmp_path):
    sink = ListSink()
    p = Pipeline()
    s = p.source(ListSource([small_stream]), id="src")
    p.sink(sink, p.op(Interrupt(), s), id="mem")
    p.sink(str(tmp_path / "out.npz"), s, id="file")
    with pytest.raises(KeyboardInterrupt):
        tectum.run(p)
    assert sink.aborted and not sink.closed
    assert list(tmp_path.iterdir()) == []


def test_a_stopped_async_source_is_closed_in_order():
    """A run cancelled while an async source (a socket, a device) is held
    at a packet it gave closes the source's packet generator before the
    source: the generator's own clean-up (a network source flushes what it
    holds) runs inside the run, in order, not later from the garbage
    collector (here the sink cancels the run as its third packet arrives)."""
    order: list[str] = []
    scope = trio.CancelScope()

    class _Live(tectum.Source):
        name = "live_order_test"

        async def apackets(self):
            try:
                for t in range(1000):
                    yield EventPacket.from_arrays([t], [0], [0], [1], sensor=(4, 4), t_start=t, t_end=t + 1)
            finally:
                order.append("generator")

        def close(self) -> None:
            order.append("source")

    class _Stop(ListSink):
        def write(self, packet) -> None:
            super().write(packet)
            if len(self.packets) == 3:
                scope.cancel()

    p = Pipeline()
    p.sink(_Stop(), p.source(_Live(), id="src"), id="out")

    async def main() -> None:
        with scope:
            await tectum.arun(p)

    trio.run(main)
    assert order == ["generator", "source"]
