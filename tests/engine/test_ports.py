"""Named input ports joined by watermark, the merges they replaced, offloaded
operators and the operator life cycle (warmup, on_tick)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

import tectum
from tectum import EventPacket, FramePacket, Kind, Operator, Pipeline, PipelineError, Port, PosePacket, Stepper, concat
from tectum.testing import ListSink, ListSource, assert_batch_invariant, feed_ports


def events(t0: int, t1: int, step: int = 10, sensor: tuple[int, int] = (8, 6)) -> EventPacket:
    t = np.arange(t0, t1, step, dtype=np.int64)
    return EventPacket(t, (t % sensor[0]).astype(np.uint16), (t % sensor[1]).astype(np.uint16),
                       np.where(t % 20 == 0, 1, -1).astype(np.int8), sensor=sensor, t_start=t0, t_end=t1)


def poses(t0: int, t1: int, step: int = 50, **extra: np.ndarray) -> PosePacket:
    t = np.arange(t0, t1, step, dtype=np.int64)
    pos = np.stack([t * 1e-3, np.zeros(len(t)), np.zeros(len(t))], axis=1)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    return PosePacket(t, position=pos, orientation=q, t_start=t0, t_end=t1, **extra)


def pieces(pkt, cuts):
    bounds = [pkt.t_start, *cuts, pkt.t_end]
    return [pkt.slice_time(a, b) for a, b in zip(bounds, bounds[1:])]


class Recorder(Operator):
    """Records every batch; emits the events of each batch with a column
    holding the number of poses seen so far that are <= the event's time."""

    name = "map.recorder_test"
    inputs = {"events": Port(Kind.EVENTS), "poses": Port(Kind.POSES)}
    produces = (Kind.EVENTS,)

    def __init__(self) -> None:
        self.calls: list[dict[str, tuple[int, int, int]]] = []
        self.pose_t = np.empty(0, np.int64)

    def process_ports(self, ports):
        self.calls.append({k: (v.t_start, v.t_end, len(v)) for k, v in ports.items()})
        if "poses" in ports:
            self.pose_t = np.concatenate([self.pose_t, ports["poses"].t])
        ev = ports.get("events")
        if ev is None:
            return []
        seen = np.searchsorted(self.pose_t, ev.t, side="right").astype(np.int64)
        return [ev.with_columns(poses_before=seen)]


class Passing(Operator):
    """Passes the packets of one kind on (what its inputs' merge gave it)."""

    name = "filter.passing_test"

    def __init__(self, kind: Kind) -> None:
        self.consumes = self.produces = (kind,)  # type: ignore[misc]

    def process(self, packet):
        return [packet]


def _registry_with(*classes):
    reg = tectum.get_registry()
    for c in classes:
        if c.name not in reg.operators:
            reg.add("operator", c, "tests")
    return reg


def test_ports_are_joined_by_watermark_in_a_run():
    ev, ps = events(200, 700), poses(0, 900)
    p = Pipeline()
    a = p.source(ListSource(pieces(ev, [300, 500])), id="cam")
    b = p.source(ListSource(pieces(ps, [500])), id="gt")
    rec = Recorder()
    p.op(rec, events=a, poses=b, id="rec")
    sink = ListSink()
    p.sink(sink, "rec")
    tectum.run(p)
    # every call covers one interval on every port, back to back
    spans = [{v[:2] for v in c.values()} for c in rec.calls]
    assert all(len(s) == 1 for s in spans)
    flat = [next(iter(s)) for s in spans]
    assert all(a[1] == b[0] for a, b in zip(flat, flat[1:]))
    got = sink.events()
    assert np.array_equal(got.t, ev.t)
    # every event saw every pose up to its time before it was processed
    assert np.array_equal(got.columns["poses_before"], np.searchsorted(ps.t, ev.t, side="right"))


def test_one_source_fills_ports_by_kind():
    ev, ps = events(0, 1000), poses(0, 1000)
    mixed = []
    for a, b in ((0, 400), (400, 1000)):  # a source of two kinds, interleaved in time
        mixed += [ps.slice_time(a, b), ev.slice_time(a, b)]
    p = Pipeline()
    src = p.source(ListSource(mixed), id="folder")
    p.op(Recorder(), src, id="rec")
    sink = ListSink()
    p.sink(sink, "rec")
    tectum.run(p)
    assert np.array_equal(sink.events().columns["poses_before"], np.searchsorted(ps.t, ev.t, side="right"))


def test_a_multi_kind_one_input_operator_sees_kinds_in_time_order():
    """Regression: merged kind by kind, an events+poses operator got poses
    for [300, 500) µs before the events for [200, 300). Now every pose
    before an events packet's end comes before that packet, and no pose
    comes ahead of the events before it."""
    all_poses = [poses(0, 300), poses(300, 500), poses(500, 600)]
    pose_t = np.concatenate([q.t for q in all_poses])

    class Both(Operator):
        name = "filter.both_test"
        consumes = (Kind.EVENTS, Kind.POSES)
        produces = (Kind.EVENTS,)

        def __init__(self):
            self.seen: list[tuple[str, int, int]] = []
            self.poses_seen = np.empty(0, np.int64)

        def process(self, packet):
            self.seen.append((str(packet.kind), packet.t_start, packet.t_end))
            if packet.kind == Kind.POSES:
                self.poses_seen = np.concatenate([self.poses_seen, packet.t])
            else:  # every pose before this packet's end is already here
                assert np.array_equal(self.poses_seen, pose_t[pose_t < packet.t_end]), (packet, self.poses_seen)
            return []

    op = Both()
    p = Pipeline()
    a = p.source(ListSource(pieces(events(200, 600), [300, 400])), id="cam")
    b = p.source(ListSource(all_poses), id="gt")
    p.op(op, [a, b], id="both")
    p.sink(ListSink(), "both")
    tectum.run(p)
    # time order across kinds: no packet starts before one already delivered
    starts = [s[1] for s in op.seen]
    assert starts == sorted(starts), op.seen


def test_merging_frame_streams_with_empty_ticks():
    """Regression: the (0, 0, 0) placeholder image of an empty repr tick
    made merging frame streams raise ValueError."""

    def frames(ts, t0, t1):
        return FramePacket(np.array(ts, np.int64), images=np.ones((len(ts), 3, 4), np.float32),
                           t_start=t0, t_end=t1)

    p = Pipeline()
    a = p.source(ListSource([FramePacket.empty(0, 100), frames([150], 100, 200)]), id="a")
    b = p.source(ListSource([frames([50], 0, 100), FramePacket.empty(100, 200)]), id="b")
    p.op(Passing(Kind.FRAMES), [a, b], id="m")
    sink = ListSink()
    p.sink(sink, "m")
    tectum.run(p)
    got = concat([q for q in sink.packets if len(q)])
    assert got.t.tolist() == [50, 150] and got.images.shape == (2, 3, 4)


def test_merging_pose_streams_whose_optional_fields_differ():
    """Regression: KeyError when one pose stream has an optional field."""
    w = np.ones((2, 3))
    p = Pipeline()
    a = p.source(ListSource([poses(0, 100)]), id="a")
    b = p.source(ListSource([poses(10, 100, angular_velocity=w)]), id="b")
    p.op(Passing(Kind.POSES), [a, b], id="m")
    sink = ListSink()
    p.sink(sink, "m")
    tectum.run(p)
    got = concat([q for q in sink.packets if len(q)])
    assert got.t.tolist() == [0, 10, 50, 60]
    av = got.angular_velocity
    assert np.isnan(av[[0, 2]]).all() and (av[[1, 3]] == 1).all()


@pytest.mark.parametrize("how, message", [
    (lambda p, a, b: p.op("map.recorder_test", events=a), "required port(s) 'poses' (poses) not connected"),
    (lambda p, a, b: p.op("map.recorder_test", events=a, poses=a), "port 'poses' takes poses but 'cam' provides"),
    (lambda p, a, b: p.op("map.recorder_test", [a, b, "cam2"]), "could take 'cam', 'cam2'"),
    (lambda p, a, b: p.op("map.recorder_test", {"events": a, "pose": b}), "has no port(s) ['pose']"),
    (lambda p, a, b: p.op("filter.refractory", {"events": a}), "has no named ports"),
])
def test_port_wiring_errors_name_node_and_port(how, message):
    _registry_with(Recorder)
    p = Pipeline()
    a = p.source(ListSource([events(0, 100)]), id="cam")
    b = p.source(ListSource([poses(0, 100)]), id="gt")
    p.source(ListSource([events(0, 100)]), id="cam2")
    node = how(p, a, b)
    p.sink(ListSink(), node)
    with pytest.raises(PipelineError) as e:
        p.validate()
    assert message in str(e.value)
    assert repr(node) in str(e.value)


def test_ports_from_toml(tmp_path):
    _registry_with(Recorder)
    p = Pipeline.from_dict({
        "source": [{"id": "cam", "uri": "pattern:", "params": {"duration_us": 1000}},
                   {"id": "cam2", "uri": "pattern:", "params": {"duration_us": 1000}}],
        "op": [{"id": "rec", "name": "map.recorder_test", "input": {"events": "cam"}}],
        "sink": [{"uri": "null:", "input": "rec"}],
    })
    with pytest.raises(PipelineError, match="'poses' \\(poses\\) not connected"):
        p.validate()


def test_ports_batch_invariance_and_stepper_agree_with_run():
    _registry_with(Recorder)
    ev, ps = events(0, 2000, 7), poses(0, 2000, 130)
    assert_batch_invariant(Recorder, {"events": ev, "poses": ps}, max_examples=10)
    ref = feed_ports(Recorder(), {"events": [ev], "poses": [ps]})
    p = Pipeline()
    a = p.source(ListSource([ev]), id="cam")
    b = p.source(ListSource([ps]), id="gt")
    p.op("map.recorder_test", events=a, poses=b, id="rec")
    with Stepper(p, outputs=["rec"]) as step:
        out = []
        for q in pieces(ev, [500, 1500]):
            out += step.push(q, into="cam")["rec"]
        for q in pieces(ps, [1000]):
            out += step.push(q, into="gt")["rec"]
        out += step.end("cam")["rec"] + step.end("gt")["rec"]
    tectum.testing.assert_streams_equal(ref, out, "stepper")


def test_batch_invariance_check_catches_a_port_dependent_operator():
    class Sloppy(Recorder):
        def process_ports(self, ports):  # counts calls: depends on the split
            self.calls.append({})
            ev = ports.get("events")
            return [] if ev is None else [ev.with_columns(calls=np.full(len(ev), len(self.calls)))]

    with pytest.raises(AssertionError):
        assert_batch_invariant(Sloppy, {"events": events(0, 500), "poses": poses(0, 500)}, max_examples=5)


class Progress(ListSink):
    """A sink that lets other threads wait until it has written up to a time."""

    def __init__(self) -> None:
        super().__init__()
        self.cond = threading.Condition()
        self.reached = -1

    def write(self, packet):
        super().write(packet)
        with self.cond:
            self.reached = packet.t_end
            self.cond.notify_all()

    def wait_for(self, t_end: int, timeout: float) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: self.reached >= t_end, timeout)


class Slow(Operator):
    """Works on each packet until the fast branch has delivered the same
    packet to its sink: possible only when this operator runs off the event
    loop (inline, it would hold the loop and wait forever)."""

    name = "filter.slow_test"
    heavy = True

    def __init__(self, fast_sink: Progress) -> None:
        self.fast_sink = fast_sink
        self.threads: set[int] = set()

    def process(self, packet):
        self.threads.add(threading.get_ident())
        if not self.fast_sink.wait_for(packet.t_end, 2):
            raise RuntimeError("the fast branch did not deliver while this operator worked")
        return [packet]


def _fast_and_slow(offload):
    ev = events(0, 5000)
    p = Pipeline(max_events=50)
    src = p.source(ListSource([ev]), id="cam")
    fast_sink = Progress()
    slow = Slow(fast_sink)
    p.op(slow, src, id="slow", offload=offload, buffer=4)
    fast = p.op("filter.refractory", src, id="fast", period_us=1)
    slow_sink = ListSink()
    p.sink(slow_sink, "slow")
    p.sink(fast_sink, fast)
    return p, slow, slow_sink, fast_sink, ev


def test_a_heavy_operator_runs_off_the_event_loop():
    p, slow, slow_sink, fast_sink, ev = _fast_and_slow(offload=None)  # heavy: offloaded by default
    tectum.run(p)
    assert threading.get_ident() not in slow.threads
    assert np.array_equal(slow_sink.events().t, ev.t)
    assert np.array_equal(fast_sink.events().t, ev.t)


def test_without_offload_the_slow_operator_blocks_the_loop():
    p, slow, *_ = _fast_and_slow(offload=False)
    with pytest.raises(tectum.NodeError, match="did not deliver"):
        tectum.run(p)


def test_warmup_runs_before_the_first_packet_and_on_tick_after_each():
    log: list[tuple[str, int]] = []

    class Life(Operator):
        name = "filter.life_test"

        def warmup(self):
            log.append(("warmup", 0))

        def process(self, packet):
            log.append(("process", packet.t_end))
            return [packet]

        def on_tick(self, watermark):
            log.append(("tick", watermark))
            return []

    p = Pipeline()
    src = p.source(ListSource(pieces(events(0, 300), [100, 200])), id="cam")
    p.op(Life(), src, id="life")
    p.sink(ListSink(), "life")
    tectum.run(p)
    assert log[0] == ("warmup", 0)
    assert log[1:] == [("process", 100), ("tick", 100), ("process", 200), ("tick", 200),
                       ("process", 300), ("tick", 300)]
