"""Embedding: direct stepping, and a background thread for control loops."""

from __future__ import annotations

import time

import pytest

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
