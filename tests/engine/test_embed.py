"""Embedding: direct stepping, and a background thread for control loops."""

from __future__ import annotations

import time

import numpy as np
import pytest
import trio

import tectum
from tectum import Pipeline, Stepper, ThreadedPipeline
from tectum.plugins.filter import Refractory
from tectum.testing import ListSink, ListSource, assert_streams_equal, feed


def test_stepper_push_and_end(small_stream):
    p = Pipeline()
    s = p.source(ListSource([]), id="cam")
    rf = p.op("filter.refractory", s, id="rf", period_us=300)
    sink = ListSink()
    p.sink(sink, rf)
    got = []
    with Stepper(p, outputs=["rf"]) as step:
        for piece in small_stream.batches(100):
            got += step.push(piece)["rf"]
        got += step.end()["rf"]
    assert_streams_equal(feed(Refractory(300), [small_stream]), got)
    assert_streams_equal(got, sink.packets)
    assert sink.closed


def test_threaded_pipeline_latest_and_callbacks():
    p = Pipeline(pace=1.0)
    s = p.source("pattern:", id="cam", duration_us=3_000_000, sensor="64x48", window_us=1000)
    p.op("filter.refractory", s, id="rf", period_us=300)
    seen = []
    tp = ThreadedPipeline(p, watch=["rf"])
    tp.on_output("rf", lambda pkt: seen.append(pkt.t_end))
    with tp:
        deadline = time.monotonic() + 30
        latest = None
        while latest is None and time.monotonic() < deadline:  # a 1 kHz control loop
            latest = tp.latest("rf")
            time.sleep(0.001)
        assert latest is not None
        pkt, when = latest
        assert isinstance(pkt, tectum.EventPacket) and when <= time.monotonic()
    assert tp.done and seen == sorted(seen) and len(seen) >= 1
    assert tp.stats is not None and tp.stats.nodes["rf"].packets_in >= 1


def test_threaded_pipeline_reraises_errors():
    p = Pipeline()
    p.sink(ListSink(), p.source("pattern:", id="cam", duration_us=1000, speed=-1.0))
    tp = ThreadedPipeline(p, watch=["cam"]).start()
    with pytest.raises(tectum.NodeError, match="node 'cam'"):
        tp.join(timeout=60)


class _Silent(tectum.Source):
    """A live source that sends nothing until the run is stopped."""

    name = "silent"

    async def apackets(self):  # type: ignore[no-untyped-def]
        await trio.sleep(60)
        yield tectum.EventPacket.empty((4, 4), 0, 1)


def _written(tmp_path):
    """A pipeline whose run wrote ``clean.npz``, and the events it holds."""
    p = Pipeline()
    cam = p.source("pattern:", duration_us=100_000, sensor="32x24", noise_hz=2.0)
    rf = p.op("filter.refractory", cam, period_us=1000)
    p.sink(str(tmp_path / "clean.npz"), rf)
    tectum.run(p)
    return p, np.load(tmp_path / "clean.npz")["t"]


def test_stepping_a_pipeline_that_ran_keeps_its_file(tmp_path):
    p, t = _written(tmp_path)
    assert len(t) > 100
    two = tectum.EventPacket.from_arrays([10, 20], [3, 4], [5, 5], [1, 0], sensor=(32, 24))
    with Stepper(p, outputs=["refractory"]) as step:
        out = step.push(two)["refractory"]
    assert np.array_equal(np.load(tmp_path / "clean.npz")["t"], t)  # README: it ended with 2 events
    assert sum(len(q) for q in out) == 2 and step.left_out == ("clean",)
    with Stepper(p, outputs=["refractory"], file_sinks=True) as step:  # asked for: the file is the stepping's
        step.push(two)
    assert np.load(tmp_path / "clean.npz")["t"].tolist() == [10, 20]


def test_watching_a_pipeline_that_ran_keeps_its_file(tmp_path):
    p, t = _written(tmp_path)
    before = (tmp_path / "clean.npz").stat()
    with ThreadedPipeline(p, watch=["refractory"]) as live:
        time.sleep(0.5)
    after = (tmp_path / "clean.npz").stat()
    assert (after.st_ino, after.st_mtime_ns) == (before.st_ino, before.st_mtime_ns)  # not written again
    assert np.array_equal(np.load(tmp_path / "clean.npz")["t"], t)
    with ThreadedPipeline(p, watch=["refractory"]) as live:
        latest = live.wait_latest("refractory", timeout=30)
    assert latest is not None and isinstance(latest[0], tectum.EventPacket)
    assert live.left_out == ("clean",)


def test_wait_latest_times_out_and_returns_none_at_the_end():
    p = Pipeline()
    p.sink(ListSink(), p.source(_Silent(), id="cam"))
    with ThreadedPipeline(p, watch=["cam"]) as live:
        assert live.latest("cam") is None
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match="'cam' emitted nothing within 0.2 s"):
            live.wait_latest("cam", timeout=0.2)
        assert 0.15 < time.monotonic() - t0 < 5
    q = Pipeline()
    q.sink(ListSink(), q.source(ListSource([]), id="cam"))
    with ThreadedPipeline(q, watch=["cam"]) as live:
        assert live.wait_latest("cam", timeout=30) is None  # ended without a packet: no wait for ever
