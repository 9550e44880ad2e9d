"""The engine's fast paths build the same packets and counts as the plain ones."""

from __future__ import annotations

from types import MappingProxyType

import numpy as np
import pytest

import tectum
from tectum import EventPacket
from tectum._packet import join_consecutive
from tectum.sinks.null import NullSink
from tectum.testing import ListSource


def _events(t: np.ndarray) -> EventPacket:
    n = len(t)
    rng = np.random.default_rng(0)
    return EventPacket(t.astype(np.int64), rng.integers(0, 8, n).astype(np.uint16),
                       rng.integers(0, 6, n).astype(np.uint16), np.where(rng.random(n) < 0.5, 1, -1).astype(np.int8),
                       sensor=(8, 6), t_start=int(t[0]) - 3, t_end=int(t[-1]) + 5)


@pytest.mark.parametrize("t", [np.arange(0, 50, 2), np.array([0, 0, 1, 4, 4, 4, 9, 10])], ids=["distinct", "runs"])
@pytest.mark.parametrize("checked", [False, True])
def test_event_by_event_pieces_are_plain_immutable_views(t: np.ndarray, checked: bool) -> None:
    pk = _events(t)
    if checked:
        pk.validate()
    pieces = list(pk.batches(1))
    lo, i = pk.t_start, 0
    for q in pieces:
        assert type(q) is EventPacket and q.checked is checked
        with pytest.raises(AttributeError):
            q.t_end = 0  # type: ignore[misc]
        assert q.sensor == pk.sensor and q.column_names == pk.column_names and q.columns == {}
        assert type(q.columns) is MappingProxyType  # read-only, like any packet's
        assert q._at in (-1, i)  # not known, or where it starts in the arrays (a join takes it for that)
        m = len(q)
        assert m >= 1 and np.all(q.t == q.t[0])  # one timestamp per packet
        for name in ("t", "x", "y", "p"):
            assert np.array_equal(q[name], pk[name][i:i + m])
            assert q[name].ndim == 1 and q[name].dtype == pk[name].dtype and np.shares_memory(q[name], pk[name])
        assert q.t_start == lo and q.t[0] >= lo
        lo, i = q.t_end, i + m
    assert i == len(pk) and lo == pk.t_end and pieces[-1].t_end == pk.t_end
    assert [int(q.t[0]) for q in pieces] == sorted(set(t.tolist()))
    # a trusted view is a plain, immutable EventPacket too
    v = pk.slice_time(int(t[1]), int(t[-1]))
    assert type(v) is EventPacket and v.checked is checked
    with pytest.raises(AttributeError):
        v.x = v.y  # type: ignore[misc]


class _Twice(tectum.Operator):
    """Emits each packet twice (a chain's next step must see both)."""

    name = "filter.twice_hot_path_test"

    def process(self, packet: EventPacket) -> list[EventPacket]:
        return [packet, packet]


def test_event_by_event_chain_counts_and_taps() -> None:
    pk = _events(np.arange(0, 300, 3))

    def build() -> tectum.Pipeline:
        p = tectum.Pipeline(max_events=1)
        a = p.op(_Twice(), p.source(ListSource([pk]), id="src"), id="a")
        b = p.op(_Twice(), a, id="b")
        p.sink(NullSink(), b, id="sink")
        return p

    stats = tectum.run(build())
    n = len(pk)
    assert stats.nodes["a"].events_in == n and stats.nodes["a"].events_out == 2 * n
    assert stats.nodes["b"].events_in == 2 * n and stats.nodes["b"].events_out == 4 * n
    assert stats.nodes["sink"].events_in == 4 * n and stats.nodes["sink"].packets_in == 4 * n
    with tectum.Stepper(build(), outputs=["a"]) as s:  # a tapped node still hands its outputs out
        got = s.push(pk.slice_time(0, 9))["a"]
    assert len(got) == 2 and all(len(q) == 3 for q in got)  # a Stepper pushes packets whole


def _stream(n: int = 2000) -> EventPacket:
    rng = np.random.default_rng(3)
    t = np.sort(rng.integers(0, 50_000, n))
    return EventPacket.from_arrays(t, rng.integers(0, 64, n), rng.integers(0, 48, n), rng.choice([-1, 1], n),
                                   sensor=(64, 48), t_start=0, t_end=50_000).validate()


def _same(a: EventPacket, b: EventPacket) -> None:
    for k in ("t", "x", "y", "p"):
        assert np.array_equal(getattr(a, k), getattr(b, k)) and getattr(a, k).dtype == getattr(b, k).dtype
    assert (a.t_start, a.t_end, a.sensor, a.checked) == (b.t_start, b.t_end, b.sensor, b.checked)


def test_joining_slices_that_lie_end_to_end_makes_a_view_else_a_copy() -> None:
    ev = _stream()
    cuts = [ev.slice_time(a, a + 1000) for a in range(0, 50_000, 1000)]
    whole = ev.slice_time(cuts[3].t_start, cuts[40].t_end)
    joined = join_consecutive(cuts[3:41])
    _same(joined, whole)
    assert all(np.shares_memory(getattr(joined, k), getattr(ev, k)) for k in ("t", "x", "y", "p"))  # no copy
    # a gap (one packet left out), slices of separate arrays, strided views: copied, still right
    gap = cuts[3:10] + cuts[11:20]
    got = join_consecutive(gap)
    _same(got, _concat_reference(gap))
    assert not np.shares_memory(got.t, ev.t)
    other = _stream()
    mixed = [cuts[3], other.slice_time(cuts[4].t_start, cuts[4].t_end)]
    _same(join_consecutive(mixed), _concat_reference(mixed))
    every_other = EventPacket._trusted(ev.t[::2], ev.x[::2], ev.y[::2], ev.p[::2], ev.sensor, 0, 50_000, {})
    halves = [every_other.slice_time(0, 25_000), every_other.slice_time(25_000, 50_000)]
    got = join_consecutive(halves)
    _same(got, every_other)
    assert not np.shares_memory(got.t, ev.t)
    # columns out of step (x cut elsewhere than t): copied
    a, b = cuts[5], cuts[6]
    skewed = EventPacket._trusted(b.t, ev.x[len(ev) - len(b):], b.y, b.p, b.sensor, b.t_start, b.t_end, {}, True)
    got = join_consecutive([a, skewed])
    assert np.array_equal(got.x, np.concatenate([a.x, skewed.x]))


def _concat_reference(pkts: list[EventPacket]) -> EventPacket:
    return EventPacket._trusted(*(np.concatenate([getattr(q, k) for q in pkts]) for k in ("t", "x", "y", "p")),
                                pkts[0].sensor, pkts[0].t_start, pkts[-1].t_end, {},
                                all(q.checked for q in pkts))


def test_slices_know_where_they_lie_so_a_join_needs_no_pointers(monkeypatch: pytest.MonkeyPatch) -> None:
    """Slices (and slices of slices, and of a packet with columns added or
    removed) record their index in the owner arrays: joining them is a view
    found without the pointer kernel, equal to the slice of the whole."""
    import tectum._packet as packet_module

    def no_pointers(*args: object) -> int:
        raise AssertionError("the join looked at pointers")

    monkeypatch.setattr(packet_module, "_slice_index", no_pointers)
    ev = _stream()
    part = ev.with_columns(w=np.zeros(len(ev))).without_columns("w").slice_time(7_000, 41_000)
    cuts = [part.slice_time(a, a + 700) for a in range(7_000, 41_000, 700)]
    joined = join_consecutive(cuts[2:30])
    _same(joined, ev.slice_time(cuts[2].t_start, cuts[29].t_end))
    assert all(np.shares_memory(getattr(joined, k), getattr(ev, k)) for k in ("t", "x", "y", "p"))
    again = join_consecutive([joined.slice_time(None, 20_000), joined.slice_time(20_000, None), cuts[30]])
    _same(again, ev.slice_time(cuts[2].t_start, cuts[30].t_end))
    # arrays not known to be slices (built by hand): the pointer kernel decides
    hand = [EventPacket._trusted(q.t, q.x, q.y, q.p, q.sensor, q.t_start, q.t_end, {}, True) for q in cuts[:2]]
    with pytest.raises(AssertionError, match="pointers"):
        join_consecutive(hand)


@pytest.mark.parametrize("checked", [False, True, "first not"])
def test_a_packet_that_goes_back_in_time_is_stopped_checked_or_not(checked: bool | str) -> None:
    ev = _stream()
    a, b = ev.slice_time(0, 20_000), ev.slice_time(10_000, 30_000)  # b starts before a ends
    if not checked:
        a, b = (EventPacket(q.t, q.x, q.y, q.p, sensor=q.sensor, t_start=q.t_start, t_end=q.t_end) for q in (a, b))
    if checked == "first not":  # the mark set by the full check holds for a checked packet after it
        a = EventPacket(a.t, a.x, a.y, a.p, sensor=a.sensor, t_start=a.t_start, t_end=a.t_end)
        assert not a.checked and b.checked
    else:
        assert a.checked is checked and b.checked is checked
    p = tectum.Pipeline()
    p.sink(NullSink(), p.source(ListSource([a, b]), id="cam"), id="sink")
    with pytest.raises(tectum.NodeError, match="source 'cam': events packet \\[10000, 30000\\) starts before the "
                                               "previous one ended \\(20000 µs\\)"):
        tectum.run(p)


class _ImuOnly(tectum.Sink):
    """Takes IMU samples only (events reaching it are counted as not written)."""

    name = "imu_only_hot_path_test"
    consumes = (tectum.Kind.IMU,)

    def __init__(self) -> None:
        self.got: list[tectum.Packet] = []

    def write(self, packet: tectum.Packet) -> None:
        self.got.append(packet)


@pytest.mark.parametrize("trio", [False, True])
def test_a_sink_written_through_takes_its_kinds_and_counts_the_others(trio: bool) -> None:
    ev = _stream()
    imu = tectum.ImuPacket(np.arange(0, 50_000, 1000), gyro=np.zeros((50, 3)), accel=np.zeros((50, 3)),
                           t_start=0, t_end=50_000)
    sink, every = _ImuOnly(), tectum.testing.ListSink()
    p = tectum.Pipeline(max_events=300)
    if trio:  # two sources merged by an operator: tasks under trio, the sinks still written inline
        up = p.op(_Twice(), [p.source(ListSource([ev]), id="ev"), p.source(ListSource([imu]), id="imu")])
    else:
        up = p.op(_Twice(), p.source(ListSource([imu, ev]), id="ev"))
    p.sink(sink, up, id="sink")
    p.sink(every, up, id="every")
    stats = tectum.run(p)
    assert stats.nodes["sink"].not_written == {"events": 2 * len(ev)}  # _Twice: each packet twice
    assert [len(q) for q in sink.got] == [50]
    assert stats.nodes["every"].events_in == 2 * len(ev) and stats.latency["every"].count == len(every.packets)
    got = [q for q in every.packets if isinstance(q, EventPacket)]
    tectum.testing.assert_streams_equal([ev], got[::2])


def test_a_paced_source_counts_how_late_it_released_each_piece() -> None:
    """Every paced piece is counted once in ``released_late``: on a mock
    clock (no OS, nothing else to run) none is late; an operator that takes
    3 ms of the clock makes the next piece late by up to that. Unpaced runs
    record none."""
    import trio

    ev = _stream(300)

    class _Stall(tectum.Operator):
        name = "filter.stall_hot_path_test"

        def __init__(self, at: int) -> None:
            self.at, self.n = at, 0

        def process(self, packet: EventPacket) -> list[EventPacket]:
            self.n += 1
            if self.n == self.at:
                trio.lowlevel.current_clock().jump(0.003)  # type: ignore[attr-defined]
            return [packet]

    def run(at: int) -> tectum.Stats:
        p = tectum.Pipeline(pace=1.0, max_latency_us=1000)
        p.sink(NullSink(), p.op(_Stall(at), p.source(ListSource([ev]), id="src")), id="out")
        return trio.run(tectum.arun, p, clock=trio.testing.MockClock(autojump_threshold=0))

    stats = run(0)
    late = stats.released_late["src"]
    assert late.count == stats.nodes["src"].packets_out > 10 and late.percentiles()["max"] < 1.0
    stalled = run(5).released_late["src"].percentiles()
    # µs: stalled from 5 to 8 ms, so the window [5, 6) ms that closed at 6 ms went out at 8 ms
    assert stalled["max"] == pytest.approx(2000, rel=0.02)
    plain = tectum.Pipeline()
    plain.sink(NullSink(), plain.source(ListSource([ev]), id="src"))
    assert tectum.run(plain).released_late == {}


class _Seen(tectum.Operator):
    """Passes packets on and keeps them (what the engine handed it)."""

    name = "filter.seen_hot_path_test"

    def __init__(self) -> None:
        self.seen: list[EventPacket] = []

    def process(self, packet: EventPacket) -> list[EventPacket]:
        self.seen.append(packet)
        return [packet]


def test_big_slices_lying_end_to_end_go_in_as_one_view_others_as_they_are() -> None:
    from tectum._scheduler import _SMALL

    rng = np.random.default_rng(5)
    n = 12 * _SMALL
    t = np.sort(rng.integers(0, 10 * n, n))
    ev = EventPacket.from_arrays(t, rng.integers(0, 64, n), rng.integers(0, 48, n), rng.choice([-1, 1], n),
                                 sensor=(64, 48), t_start=0, t_end=10 * n).validate()
    step = int(ev.t[2 * _SMALL])  # about 2 x _SMALL events a slice
    cuts = [ev.slice_time(a, a + step) for a in range(0, ev.t_end, step)]
    copies = [EventPacket(q.t.copy(), q.x.copy(), q.y.copy(), q.p.copy(), sensor=q.sensor, t_start=q.t_start,
                          t_end=q.t_end).validate() for q in cuts]
    for packets, joined in ((cuts, True), (copies, False)):
        op, sink = _Seen(), tectum.testing.ListSink()
        p = tectum.Pipeline(max_events=5 * _SMALL)
        p.sink(sink, p.op(op, p.source(ListSource(packets), id="src")), id="sink")
        tectum.run(p)
        tectum.testing.assert_streams_equal([ev], sink.packets)
        if joined:  # slices end to end: views of the whole, as large as max_events allows
            assert len(op.seen) < len(packets) and max(len(q) for q in op.seen) > 2 * _SMALL
            assert all(len(q) <= 5 * _SMALL and np.shares_memory(q.t, ev.t) for q in op.seen)
        else:  # separate arrays of _SMALL events or more: each goes in as it is (no copy)
            assert len(op.seen) == len(packets) and all(a.t is b.t for a, b in zip(op.seen, packets))


class _Counted(tectum.Operator):
    """Counts the calls of every copy (the default warm-up runs a copy)."""

    name = "filter.counted_hot_path_test"
    calls: list[tuple[str, int]] = []

    def __init__(self, mode: str = "a", width: int = 1) -> None:
        self.mode, self.width = mode, width

    def process(self, packet: EventPacket) -> list[EventPacket]:
        _Counted.calls.append((self.mode, len(packet)))
        return [packet]


def test_the_default_warmup_runs_once_per_class_and_settings() -> None:
    """A pipeline built per run warms an operator up once per process for
    each class and settings (its kernels stay compiled), and again for
    other settings; the run itself is untouched."""
    ev = _stream(50)

    def run(op: tectum.Operator) -> list[tuple[str, int]]:
        _Counted.calls = []
        p = tectum.Pipeline()
        p.sink(NullSink(), p.op(op, p.source(ListSource([ev]))))
        tectum.run(p)
        return _Counted.calls

    warm = run(_Counted("first-run"))  # the warm-up's 16 synthetic events, then the stream
    assert warm == [("first-run", 16), ("first-run", 50)]
    assert run(_Counted("first-run")) == [("first-run", 50)]
    assert run(_Counted("first-run", width=2)) == [("first-run", 16), ("first-run", 50)]  # other settings
    assert run(_Counted("other")) == [("other", 16), ("other", 50)]
    assert run(_Counted("first-run", width=2)) == [("first-run", 50)]


def _slices_with_a_gap() -> tuple[EventPacket, list[EventPacket]]:
    """A checked stream with no events in [40 000, 41 000) µs, cut in 100 µs slices."""
    ev = _stream(4000)
    keep = (ev.t < 40_000) | (ev.t >= 41_000)
    ev = EventPacket(ev.t[keep], ev.x[keep], ev.y[keep], ev.p[keep], sensor=ev.sensor, t_start=0,
                     t_end=50_000).validate()
    return ev, [ev.slice_time(a, a + 100) for a in range(0, 50_000, 100)]


@pytest.mark.parametrize("trio", [False, True])
def test_a_run_of_slices_is_taken_whole_with_whatever_breaks_it(trio: bool) -> None:
    """Slices of one packet lying end to end are taken one after another
    into a run (views, up to max_events); a slice of another sensor object,
    an unchecked copy, an IMU packet, a slice with columns each end the run
    or go in as the plain path would, and the output is the stream."""
    ev, cuts = _slices_with_a_gap()
    imu = tectum.ImuPacket(np.array([20_050]), gyro=np.zeros((1, 3)), accel=np.zeros((1, 3)), t_start=20_000,
                           t_end=20_100)
    odd = cuts[:100]  # the plain run
    q = cuts[100]
    odd.append(EventPacket._trusted(q.t, q.x, q.y, q.p, (64, 49), q.t_start, q.t_end, {}, True, q._at))  # other sensor
    odd += cuts[101:150]
    q = cuts[150]
    odd.append(EventPacket(q.t.copy(), q.x.copy(), q.y.copy(), q.p.copy(), sensor=q.sensor, t_start=q.t_start,
                           t_end=q.t_end))  # not checked: the guard's full check
    odd += cuts[151:200]
    odd.append(imu.slice_time(20_000, 20_000))  # an empty IMU packet between two slices
    odd += cuts[200:300]
    odd.append(cuts[300].with_columns(w=np.zeros(len(cuts[300]))))
    odd += cuts[301:]
    op, sink = _Seen(), tectum.testing.ListSink()
    p = tectum.Pipeline(max_events=700)
    up = p.op(op, p.source(ListSource(odd, produces=[tectum.Kind.EVENTS, tectum.Kind.IMU]), id="src"))
    p.sink(sink, up, id="sink")
    if trio:  # a second source: tasks under trio
        p.sink(tectum.testing.ListSink(), p.source(ListSource([ev]), id="other"))
    stats = tectum.run(p)
    got = [q for q in sink.packets if isinstance(q, EventPacket)]
    tectum.testing.assert_streams_equal([ev], [q.without_columns("w") if q.columns else q for q in got])
    assert all(len(q) <= 700 for q in op.seen) and len(op.seen) < len(odd) // 3
    assert sum(np.shares_memory(q.t, ev.t) for q in op.seen) > len(op.seen) - 4  # runs are views of the whole
    assert stats.nodes["src"].events_out == len(ev) and stats.nodes["src"].busy_ns > 0
    assert [len(q) for q in op.seen if q.sensor == (64, 49)] == [len(cuts[100])]  # went in alone


@pytest.mark.parametrize("case", ["back in time", "not checked"])
def test_a_slice_that_continues_the_arrays_is_still_guarded(case: str) -> None:
    """A slice at the next index of the same arrays is refused inside a
    run as anywhere when its interval starts before the last one's end (the
    events between are none), and checked in full when it is not marked
    checked (here an event past the sensor)."""
    ev, cuts = _slices_with_a_gap()
    i = next(k for k, q in enumerate(cuts) if q.t_start == 40_500)
    if case == "back in time":
        bad = ev.slice_time(40_300, 41_500)  # next index after cuts[i - 1] (no events in [40 000, 41 000))
        assert bad._at == cuts[i - 1]._at + len(cuts[i - 1]) and bad.t_start < cuts[i - 1].t_end
        message = "source 'cam': events packet \\[40300, 41500\\) starts before the previous one ended \\(40500 µs\\)"
    else:
        x = ev.x.copy()
        q = ev.slice_time(41_000, 41_500)
        x[q._at] = 64  # past the 64-px-wide sensor
        cuts = [EventPacket._trusted(c.t, x[c._at:c._at + len(c)], c.y, c.p, c.sensor, c.t_start, c.t_end, {}, True,
                                     c._at) for c in cuts]  # marked checked (the bad event is not in them)
        bad = EventPacket._trusted(q.t, x[q._at:q._at + len(q)], q.y, q.p, q.sensor, 40_500, 41_500, {}, False,
                                   q._at)
        message = "source 'cam'.*x"
    p = tectum.Pipeline()
    p.sink(NullSink(), p.op(_Seen(), p.source(ListSource(cuts[:i] + [bad]), id="cam")), id="sink")
    with pytest.raises(tectum.NodeError, match=message):
        tectum.run(p)


@pytest.mark.parametrize("column", ["x", "y", "p"])
def test_slices_at_the_next_index_of_other_arrays_are_not_joined_as_one_view(column: str) -> None:
    """Slices that continue the index of the same times but take one column
    from another array (two packets sharing ``t``) go in with their own
    values: a run is one view only where every column's array is the same."""
    ev = _stream(3000)
    other = {"x": (ev.x + 1) % 64, "y": (ev.y + 1) % 48, "p": -ev.p}[column]
    cols = {k: (other if k == column else getattr(ev, k)) for k in ("x", "y", "p")}
    twin = EventPacket._trusted(ev.t, cols["x"], cols["y"], cols["p"], ev.sensor, ev.t_start, ev.t_end, {}, True)
    cuts = [(twin if k % 6 == 5 else ev).slice_time(a, a + 500) for k, a in enumerate(range(0, 50_000, 500))]
    assert all(q._at >= 0 for q in cuts)  # each knows its index: only the arrays tell them apart
    sink = tectum.testing.ListSink()
    p = tectum.Pipeline()
    p.sink(sink, p.op(_Seen(), p.source(ListSource(cuts), id="src")), id="sink")
    tectum.run(p)
    tectum.testing.assert_streams_equal(cuts, sink.packets)


def test_slices_of_one_packet_share_one_tuple_of_its_arrays() -> None:
    """Every slice of a packet that owns its arrays (slices of slices, with
    columns added or removed, batches, the run the engine joins) carries the
    same ``_own`` tuple, those four arrays, and where it ends in them
    (``_stop``): the engine's per-slice tests that two slices are views of
    the same arrays, one after the other. Another packet of the
    same arrays has a tuple of its own (the test then falls back on the
    arrays' owners, as for packets built by hand, which carry none)."""
    ev = _stream()
    own = ev.slice_time(0, 10)._own
    assert own is not None and all(a is getattr(ev, k) for a, k in zip(own, ("t", "x", "y", "p")))
    part = ev.slice_time(7_000, 41_000)
    kin = [part, part.slice_time(9_000, 20_000), part.with_columns(w=np.zeros(len(part))).slice_time(20_000, 30_000),
           part.without_columns().slice_time(30_000, None), *part.batches(100)]
    assert all(q._own is own and q._stop == q._at + len(q) for q in kin)
    op = _Seen()
    p = tectum.Pipeline()
    p.sink(NullSink(), p.op(op, p.source(ListSource([ev.slice_time(a, a + 500) for a in range(0, 50_000, 500)]))))
    tectum.run(p)
    assert len(op.seen) == 1 and op.seen[0]._own is own and op.seen[0].slice_time(0, 100)._own is own
    twin = EventPacket._trusted(ev.t, ev.x, ev.y, ev.p, ev.sensor, ev.t_start, ev.t_end, {}, True)
    assert twin.slice_time(0, 10)._own is not own
    assert EventPacket._trusted(part.t, part.x, part.y, part.p, ev.sensor, 7_000, 41_000, {}, True, part._at)._own is None


def test_by_default_a_source_slices_go_in_as_views_of_up_to_2_18_events() -> None:
    """The default ``max_events`` (2**18): a source's 1 ms slices of one
    checked packet go in as views of more than 65,536 events a call (the
    engine's cost per call spread over 4x more events than the old default),
    never more than 2**18, and the stream comes out whole."""
    rng = np.random.default_rng(7)
    n = 600_000
    t = np.sort(rng.integers(0, 1_000_000, n))  # 600 events a 1 ms slice
    ev = EventPacket.from_arrays(t, rng.integers(0, 64, n), rng.integers(0, 48, n), rng.choice([-1, 1], n),
                                 sensor=(64, 48), t_start=0, t_end=1_000_000).validate()
    cuts = [ev.slice_time(a, a + 1000) for a in range(0, 1_000_000, 1000)]
    op, sink = _Seen(), tectum.testing.ListSink()
    p = tectum.Pipeline()
    p.sink(sink, p.op(op, p.source(ListSource(cuts))))
    tectum.run(p)
    assert tectum.BatchPolicy().max_events == 1 << 18
    sizes = [len(q) for q in op.seen]
    assert max(sizes) <= 1 << 18 and min(sizes[:-1]) > 65_536 and len(sizes) == 3
    assert all(np.shares_memory(q.t, ev.t) for q in op.seen)
    tectum.testing.assert_streams_equal([ev], sink.packets)


class _SeenTwoSlices(_Seen):
    """:class:`_Seen` that asks for runs of at most 1 ms (two 500 µs slices)."""

    name = "filter.seen_two_slices_hot_path_test"

    def join_us(self) -> int:
        return 1000


def _guard_calls(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The ``t_start`` of each packet the source's guard is called with (filled as the run goes)."""
    from tectum._boundary import Guard

    calls: list[int] = []
    plain = Guard.__call__

    def counted(self: Guard, pkt: tectum.Packet) -> tectum.Packet:
        calls.append(pkt.t_start)
        return plain(self, pkt)

    monkeypatch.setattr(Guard, "__call__", counted)
    return calls


def test_the_slice_after_a_run_starts_is_taken_without_the_guard_again(monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs of two slices (an operator's join span): the stream's first
    slice is guarded, every later one taken by the run loop's own test (the
    guard's trusted path: the same checks), the slice that starts a run
    included: one guard call per stream, not per slice or per run; the
    operator sees each run whole and the stream comes out whole."""
    calls = _guard_calls(monkeypatch)
    ev = _stream(4000)
    cuts = [ev.slice_time(a, a + 500) for a in range(0, 50_000, 500)]
    op, sink = _SeenTwoSlices(), tectum.testing.ListSink()
    p = tectum.Pipeline()
    p.sink(sink, p.op(op, p.source(ListSource(cuts), id="src")), id="sink")
    stats = tectum.run(p)
    assert [(q.t_start, q.t_end) for q in op.seen] == [(a, a + 1000) for a in range(0, 50_000, 1000)]
    assert calls == [0]
    assert stats.nodes["src"].events_out == len(ev) and stats.nodes["src"].packets_out == 50
    tectum.testing.assert_streams_equal([ev], sink.packets)


def _even_stream(n: int = 4000) -> EventPacket:
    """Events at even µs only (an odd time holds none: a slice may start there)."""
    rng = np.random.default_rng(4)
    t = np.sort(rng.integers(0, 25_000, n)) * 2
    return EventPacket.from_arrays(t, rng.integers(0, 64, n), rng.integers(0, 48, n), rng.choice([-1, 1], n),
                                   sensor=(64, 48), t_start=0, t_end=50_000).validate()


def test_a_slice_that_starts_a_run_unchecked_or_back_in_time_goes_to_the_guard(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Where a run ends (the operator's span), the next slice is taken by
    the run loop only on the guard's trusted path: one not checked goes to
    the guard (validated there, the stream whole), one that starts before
    the last one ended is refused by it, naming the source."""
    calls = _guard_calls(monkeypatch)
    ev = _even_stream()
    cuts = [ev.slice_time(a, a + 500) for a in range(0, 50_000, 500)]
    c = cuts[6]  # a view of the same arrays, not checked
    cuts[6] = EventPacket._trusted(c.t, c.x, c.y, c.p, c.sensor, c.t_start, c.t_end, {}, False, c._at, c._own)
    op, sink = _SeenTwoSlices(), tectum.testing.ListSink()
    p = tectum.Pipeline()
    p.sink(sink, p.op(op, p.source(ListSource(cuts), id="src")), id="sink")
    tectum.run(p)
    assert calls == [0, 3000]
    assert [(q.t_start, q.t_end) for q in op.seen] == [(a, a + 1000) for a in range(0, 50_000, 1000)]
    tectum.testing.assert_streams_equal([ev], sink.packets)
    cuts = [ev.slice_time(a, a + 500) for a in range(0, 50_000, 500)]
    cuts[6] = ev.slice_time(2999, 3500)  # the same events, an interval from before the last slice's end
    assert cuts[6]._at == cuts[5]._stop and cuts[6].checked
    p = tectum.Pipeline()
    p.sink(tectum.testing.ListSink(), p.op(_SeenTwoSlices(), p.source(ListSource(cuts), id="src")), id="sink")
    with pytest.raises(tectum.NodeError, match="source 'src'.*starts before.*time went backwards") as e:
        tectum.run(p)
    assert isinstance(e.value.__cause__, tectum.PacketError) and e.value.node == "src"


def test_a_sink_written_inline_records_one_latency_per_run_of_packets() -> None:
    """Packets written one after another with the same arrival are one run,
    recorded at its last write's latency when a packet of another arrival
    comes (or at the end): the counts and busy time per packet as before."""
    from tectum._scheduler import _InlineSink, _Outbox
    from tectum._stats import LatencyRecorder, Stats

    clock = iter([1.010, 1.020, 1.030, 2.500, 2.700])
    stats, out = Stats(), _Outbox({})
    sink = _InlineSink("sink", NullSink(), stats, lambda: next(clock), out)
    frame = tectum.FramePacket(np.array([5]), images=np.zeros((1, 2, 2)), t_start=0, t_end=10)
    for arrival in (1.0, 1.0, 1.0, 2.0, 2.0):
        out.arrival = arrival
        sink(frame)
    sink.flush()
    want = LatencyRecorder()
    want.add(0.030, 3)
    want.add(0.700, 2)
    got = stats.latency["sink"]
    assert (got._bins, got.count, got._max) == (want._bins, 5, pytest.approx(700_000.0))
    st = stats.nodes["sink"]
    assert (st.packets_in, st.samples_in, st.busy_ns > 0) == (5, {"frames": 5}, True)


def test_runs_of_slices_end_where_the_span_says() -> None:
    """Slices cut at every 500 µs and one µs after some of them: each run
    starts at a slice and takes the slices after it while they end within
    the operator's span (1000 µs) of its start, as a plain loop over the
    slices says (a slice ending one µs past the span starts the next run)."""
    ev = _even_stream()
    rng = np.random.default_rng(9)
    edges = sorted({0, 50_000, *range(500, 50_000, 500), *(a + 1 for a in range(500, 50_000, 500) if rng.random() < .5)})
    cuts = [ev.slice_time(a, b) for a, b in zip(edges[:-1], edges[1:])]
    expected, start, end = [], cuts[0].t_start, cuts[0].t_end
    for q in cuts[1:]:
        if q.t_end > start + 1000:
            expected.append((start, end))
            start = q.t_start
        end = q.t_end
    expected.append((start, end))
    op, sink = _SeenTwoSlices(), tectum.testing.ListSink()
    p = tectum.Pipeline()
    p.sink(sink, p.op(op, p.source(ListSource(cuts), id="src")), id="sink")
    stats = tectum.run(p)
    assert [(q.t_start, q.t_end) for q in op.seen] == expected and len(expected) == 50
    assert stats.nodes["src"].packets_out == len(expected) and stats.nodes["src"].events_out == len(ev)
    tectum.testing.assert_streams_equal([ev], sink.packets)
