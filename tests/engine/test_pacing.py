"""Pacing a recorded stream in real time: when a piece is due, the replay
origin the paced sources of a run share, the end of a packet inside a
window, and waits spent asleep (the GIL let go) instead of spinning."""

from __future__ import annotations

import gc
import threading
import time
import warnings
from typing import Any

import numpy as np
import pytest
import trio
import trio.testing

import tectum
from tectum import EventPacket, Kind, Operator, Pipeline, Port, PosePacket
from tectum.sinks.null import NullSink
from tectum.testing import ListSource


def _events(t0: int, t1: int, step: int = 10) -> EventPacket:
    t = np.arange(t0, t1, step, dtype=np.int64)
    n = len(t)
    return EventPacket(t, (t % 8).astype(np.uint16), (t % 6).astype(np.uint16), np.ones(n, np.int8),
                       sensor=(8, 6), t_start=t0, t_end=t1)


def _poses(t0: int, t1: int, step: int = 1000) -> PosePacket:
    t = np.arange(t0, t1, step, dtype=np.int64)
    return PosePacket(t, position=np.zeros((len(t), 3)), orientation=np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1)),
                      t_start=t0, t_end=t1)


class _Join(Operator):
    """Events and poses joined; passes the events on."""

    name = "map.join_pacing_test"
    inputs = {"events": Port(Kind.EVENTS), "poses": Port(Kind.POSES)}
    produces = (Kind.EVENTS,)

    def process_ports(self, ports: Any) -> list[EventPacket]:
        ev = ports.get("events")
        return [ev] if ev is not None else []


class _Clocked(tectum.Sink):
    """Notes trio's clock at each write (with the packet's end, µs)."""

    name = "clocked_pacing_test"
    consumes = (Kind.ANY,)

    def __init__(self) -> None:
        self.at: list[tuple[float, int]] = []

    def write(self, packet: Any) -> None:
        self.at.append((trio.current_time(), packet.t_end))


class _Late(tectum.Source):
    """Yields its recorded packets after ``delay_s`` of trio's clock (a
    file slow to open: on a network disk); paced like any recording."""

    name = "late_pacing_test"
    produces = (Kind.POSES,)

    @property
    def live(self) -> bool:
        return False

    def __init__(self, packets: list[Any], delay_s: float) -> None:
        self.items, self.delay_s = packets, delay_s

    async def apackets(self) -> Any:
        await trio.sleep(self.delay_s)
        for pkt in self.items:
            yield pkt


def _mock_run(p: Pipeline) -> tuple[tectum.Stats, float]:
    async def main() -> tuple[tectum.Stats, float]:
        t0 = trio.current_time()
        return await tectum.arun(p), t0

    return trio.run(main, clock=trio.testing.MockClock(autojump_threshold=0))


def test_a_window_is_due_when_it_closes() -> None:
    """A windowed piece is due when its window closes, its latency counted
    from there: a sparse stream's one sample at each window's start (1 kHz
    in 1 ms windows) is not counted a window late (on a mock clock nothing
    else delays it: 0 µs, where the sample's own time gave 1000)."""
    sink = _Clocked()
    p = Pipeline(pace=1.0, max_latency_us=1000)
    p.sink(sink, p.source(ListSource([_events(0, 20_000, step=1000)]), id="src"), id="out")
    stats, t0 = _mock_run(p)
    assert stats.latency["out"].count == 20 and stats.latency["out"].percentiles()["max"] < 1.0
    # (and released when it closed: each window at its end, on the clock)
    assert [round((at - t0) * 1e6) for at, _ in sink.at] == [t_end for _, t_end in sink.at]


def test_paced_sources_share_their_origin() -> None:
    """Two paced sources of one recording release the same instant
    together, however late one of them starts: events and 1 kHz poses
    joined in 1 ms windows, the poses' source 1.5 ms late to give its first
    packet. Its first window goes out late (0.5 ms after it closed), then
    each window is joined and written when it closes on one clock, where
    each source's own origin made every window wait 1.5 ms for the poses.
    The latency counts from a window's close, not from the poses' sample at
    its start (where every window read 1000 µs or more)."""
    sink = _Clocked()
    p = Pipeline(pace=1.0, max_latency_us=1000)
    ev = p.source(ListSource([_events(0, 20_000)]), id="events")
    ps = p.source(_Late([_poses(0, 20_000)], 0.0015), id="poses")
    p.op(_Join(), events=ev, poses=ps, id="join")
    p.sink(sink, "join", id="out")
    stats, t0 = _mock_run(p)
    written = [(round((at - t0) * 1e6), t_end) for at, t_end in sink.at]
    assert written[0] == (1500, 1000) and written[1:] == [(t, t) for t in range(2000, 20_001, 1000)]
    assert stats.released_late["poses"].percentiles()["max"] == pytest.approx(500, rel=0.02)
    lat = stats.latency["out"]
    assert lat.count == 20 and lat.percentiles()["p90"] < 2.0  # µs: 0, in its bin
    assert lat.percentiles()["max"] == pytest.approx(500, rel=0.02)


def test_a_packet_ending_inside_a_window_waits_for_the_window() -> None:
    """A packet that ends inside a window (a file source's packets, 2.5 ms
    each in 1 ms windows) is released with its window, the pacer asleep
    until then: on a mock clock (it moves only while every task waits) the
    run ends, where the pacer waited for the packet's end, already past,
    again and again, and the clock never moved on (on a real clock: a spin
    until the window closed). A watchdog thread cancels a run that hangs."""
    out = tectum.testing.ListSink()
    p = Pipeline(pace=1.0, max_latency_us=1000)
    p.sink(out, p.source(ListSource([_events(0, 2500), _events(2500, 5000)]), id="src"), id="out")

    async def main() -> bool:
        token = trio.lowlevel.current_trio_token()
        with trio.CancelScope() as scope:
            done = threading.Event()

            def watchdog() -> None:
                if not done.wait(10.0):
                    token.run_sync_soon(scope.cancel)

            threading.Thread(target=watchdog, daemon=True).start()
            try:
                await tectum.arun(p)
            finally:
                done.set()
        return scope.cancelled_caught

    assert not trio.run(main, clock=trio.testing.MockClock(autojump_threshold=0))
    # the first packet's last window [2000, 2500) goes out when the window closes, with the next's start
    assert [(q.t_start, q.t_end) for q in out.packets] == [(0, 1000), (1000, 2000), (2000, 2500), (2500, 3000),
                                                          (3000, 4000), (4000, 5000)]
    tectum.testing.assert_streams_equal([_events(0, 5000)], out.packets)


def test_a_paced_run_cancelled_inside_a_packet_closes_its_pacer() -> None:
    """A paced run cancelled while a packet is half released (a deadline,
    Ctrl-C, a live view closed) closes the pacer's generator of that
    packet's pieces inside the run, rather than leaving it suspended for
    the garbage collector, whose finaliser runs after the run has ended
    (trio's ResourceWarning "garbage collected before it had been
    exhausted")."""
    scope = trio.CancelScope()

    class _Stop(tectum.testing.ListSink):
        def write(self, packet: Any) -> None:  # the run is cancelled as the first window goes out
            super().write(packet)
            scope.cancel()

    p = Pipeline(pace=1.0, max_latency_us=1000)
    p.sink(_Stop(), p.source(ListSource([_events(0, 20_000)]), id="src"), id="out")

    async def main() -> None:
        with scope:
            await tectum.arun(p)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ResourceWarning)
        trio.run(main, clock=trio.testing.MockClock(autojump_threshold=0))
        gc.collect()
    assert not [str(w.message) for w in caught if issubclass(w.category, ResourceWarning)]


def _napped(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """Record the pacer's sleeps that let go of the GIL (seconds each)."""
    from tectum import _scheduler

    naps: list[float] = []

    def sleep(s: float) -> None:
        naps.append(s)
        time.sleep(s)

    monkeypatch.setattr(_scheduler, "_sleep", sleep)
    return naps


def test_pacing_waits_asleep(monkeypatch: pytest.MonkeyPatch) -> None:
    """On the real clock a paced source waits for its next window asleep in
    a call that lets go of the GIL (a worker thread running an offloaded
    operator takes it at once; a loaded machine gives the CPU back sooner
    to a task that slept), not yielding in a loop: it sleeps in most of the
    60 windows (a wake-up late under load may leave one without)."""
    naps = _napped(monkeypatch)
    p = Pipeline(pace=1.0, max_latency_us=1000)
    p.sink(NullSink(), p.source(ListSource([_events(0, 60_000)]), id="src"), id="out")
    tectum.run(p)
    assert len(naps) >= 30 and all(0 < s <= 2.5e-4 for s in naps)


def test_pacing_does_not_sleep_while_another_task_can_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """The pacer sleeps only while no other task could run: beside a task
    that is always runnable (it yields in a loop) it never does."""
    naps = _napped(monkeypatch)
    p = Pipeline(pace=1.0, max_latency_us=1000)
    p.sink(NullSink(), p.source(ListSource([_events(0, 30_000)]), id="src"), id="out")

    async def main() -> None:
        stop = False

        async def busy() -> None:
            while not stop:
                await trio.lowlevel.checkpoint()

        async with trio.open_nursery() as nursery:
            nursery.start_soon(busy)
            await tectum.arun(p)
            stop = True

    trio.run(main)
    assert naps == []


class _OwnClock(trio.abc.Clock):
    """A clock of the user's own (real seconds here, but the engine cannot know)."""

    def start_clock(self) -> None:
        pass

    def current_time(self) -> float:
        return time.perf_counter()

    def deadline_to_sleep_time(self, deadline: float) -> float:
        return deadline - self.current_time()


def test_pacing_on_a_clock_of_its_own_does_not_sleep_the_thread(monkeypatch: pytest.MonkeyPatch) -> None:
    """The pacer sleeps the thread only on trio's own clock, whose seconds
    are the thread's: on another clock it yields in a loop, as before."""
    naps = _napped(monkeypatch)
    out = tectum.testing.ListSink()
    p = Pipeline(pace=1.0, max_latency_us=1000)
    p.sink(out, p.source(ListSource([_events(0, 10_000)]), id="src"), id="out")
    tectum.run(p, clock=_OwnClock())
    assert naps == []
    tectum.testing.assert_streams_equal([_events(0, 10_000)], out.packets)


class _Passes(trio.abc.Instrument):
    """Counts the passes of trio's scheduler (each polls for I/O, letting go of the GIL)."""

    def __init__(self) -> None:
        self.n = 0

    def before_io_wait(self, timeout: float) -> None:
        self.n += 1


def test_pacing_keeps_the_gil_in_the_last_stretch() -> None:
    """The last stretch before a release, with no other task queued, is
    waited in a loop that keeps the GIL, not in passes of trio's scheduler
    (each lets go of it: a worker thread of an offloaded operator took it
    there and held the release up by its turn and this thread's wake-up,
    60-90 µs): a few passes a window (one before each nap), not the 20 of
    a loop of checkpoints over the last 150 µs."""
    passes = _Passes()
    p = Pipeline(pace=1.0, max_latency_us=1000)
    out = tectum.testing.ListSink()
    p.sink(out, p.source(ListSource([_events(0, 60_000)]), id="src"), id="out")
    trio.run(lambda: tectum.arun(p), instruments=[passes])
    assert passes.n / 60 <= 8
    tectum.testing.assert_streams_equal([_events(0, 60_000)], out.packets)
