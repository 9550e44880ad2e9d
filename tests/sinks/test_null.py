"""The null sink counts what reaches it: packets, and their rows."""

from __future__ import annotations

import numpy as np

import tectum
from tectum import EventPacket, PosePacket
from tectum.sinks.null import NullSink
from tectum.testing import ListSource


def test_null_sink_counts_packets_and_rows_of_any_kind() -> None:
    t = np.array([0, 0, 1, 4, 4, 4, 9], np.int64)
    n = len(t)
    ev = EventPacket(t, np.zeros(n, np.uint16), np.zeros(n, np.uint16), np.ones(n, np.int8), sensor=(2, 2))
    sink = NullSink()
    p = tectum.Pipeline(max_events=1)  # event by event: a packet per timestamp, written by the chain loop
    p.sink(sink, p.source(ListSource([ev]), id="src"), id="sink")
    stats = tectum.run(p)
    assert (sink.packets, sink.events) == (4, n) == (stats.nodes["sink"].packets_in, stats.nodes["sink"].events_in)
    poses = PosePacket(np.arange(3, dtype=np.int64), position=np.zeros((3, 3)),
                       orientation=np.tile([0.0, 0.0, 0.0, 1.0], (3, 1)))
    sink.write(poses)
    assert (sink.packets, sink.events) == (5, n + 3)
