"""An operator that makes a stream of a kind replaces its upstream's stream of
that kind: an event-frame operator on a DAVIS recording hands on its own
frames, not its frames and the APS frames interleaved (which no consumer of
``frames`` downstream could tell apart, and which a file keeping one stream
per kind refused). What it does not pass on is counted and said."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
from davis_recording import counts, davis_packets, write_davis

import tectum
from tectum import EventPacket, FramePacket, Kind, Operator, Packet, Pipeline, ResultPacket
from tectum.sources.files import open_file
from tectum.testing import ListSink, ListSource

TECTUM = [sys.executable, "-m", "tectum"]


class _Frames(Operator):
    """One int32 count frame per events packet (a stand-in for repr.*)."""

    name = "test.frames"
    consumes: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS,)
    produces: ClassVar[tuple[Kind, ...]] = (Kind.FRAMES,)

    def process(self, packet: Packet) -> list[Packet]:
        assert isinstance(packet, EventPacket)
        img = np.zeros((1, packet.sensor[1], packet.sensor[0]), np.int32)
        np.add.at(img[0], (packet.y, packet.x), 1)
        return [FramePacket([packet.t_end - 1], images=img, t_start=packet.t_start, t_end=packet.t_end)]


class _Result(Operator):
    """A result per events packet, and the events on."""

    name = "test.result"
    produces: ClassVar[tuple[Kind, ...]] = (Kind.EVENTS, Kind.RESULTS)

    def __init__(self, tag: str) -> None:
        self.tag = tag

    def process(self, packet: Packet) -> list[Packet]:
        return [packet, ResultPacket([packet.t_end - 1], [self.tag], t_start=packet.t_start, t_end=packet.t_end)]


def _run(*ops: Operator) -> tuple[ListSink, tectum.Stats, Pipeline]:
    p = Pipeline()
    up = p.source(ListSource(davis_packets()), id="src")
    for i, op in enumerate(ops):
        up = p.op(op, up, id=f"op{i}")
    sink = ListSink()
    p.sink(sink, up, id="sink")
    return sink, tectum.run(p), p


def test_an_operator_that_makes_frames_hands_on_its_own_frames_only() -> None:
    sink, stats, p = _run(_Frames())
    n = counts(davis_packets())
    frames = [q for q in sink.packets if q.kind == Kind.FRAMES and len(q)]
    assert frames and all(q.data["images"].dtype == np.int32 for q in frames)  # none of the uint8 APS frames
    assert stats.nodes["op0"].replaced == {"frames": n["frames"]}
    got = {str(q.kind) for q in sink.packets if len(q)}
    assert got == {"frames", "imu", "triggers"}  # the kinds it neither takes nor makes still pass by
    assert "[replaces upstream frames]" in p.explain()
    assert "not passed on (replaced by its own): 10 frames" in stats.report()


def test_results_of_several_operators_all_reach_the_sink() -> None:
    sink, stats, p = _run(_Result("a"), _Result("b"))
    tags = {q.items[0] for q in sink.packets if isinstance(q, ResultPacket)}
    assert tags == {"a", "b"}
    assert not stats.nodes["op1"].replaced and "replaces" not in p.explain()


def test_a_kind_the_upstream_does_not_carry_replaces_nothing() -> None:
    p = Pipeline()
    p.sink(ListSink(), p.op(_Frames(), p.source(ListSource([q for q in davis_packets() if q.kind == Kind.EVENTS]), id="src"), id="op"), id="sink")
    assert "replaces" not in p.explain()


def _cli(*args: str, ok: bool = True) -> subprocess.CompletedProcess[str]:
    r = subprocess.run([*TECTUM, *args], capture_output=True, text=True)
    assert (r.returncode == 0) == ok, r.stderr
    return r


@pytest.mark.parametrize("out", ["frames.npz", "frames.h5"])
def test_event_frames_of_a_davis_recording_to_a_file_and_back(tmp_path: Path, out: str) -> None:
    if out.endswith(".h5"):
        pytest.importorskip("h5py")
    write_davis(tmp_path / "davis.npz")
    path = str(tmp_path / out)
    r = _cli("run", str(tmp_path / "davis.npz"), "--op", "repr.event_frame:window_us=20000", "--sink", path)
    assert "1:repr.event_frame: not passed on: 10 frames from upstream (repr.event_frame makes its own frames)" \
        in r.stderr
    assert "frames 10," in _cli("info", path).stdout  # the 200 ms in 20 ms windows: 10 event frames
    again = str(tmp_path / ("again" + Path(out).suffix))
    _cli("convert", path, again)
    got = list(open_file(again).packets())
    frames = [q for q in got if q.kind == Kind.FRAMES and len(q)]
    assert sum(len(q) for q in frames) == 10
    assert all(q.data["images"].dtype == np.int32 and q.data["images"].shape[1:] == (26, 34, 2) for q in frames)
    _cli("run", again, "--sink", str(tmp_path / ("third" + Path(out).suffix)))
