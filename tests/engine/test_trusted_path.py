"""Packets are checked once: :meth:`EventPacket.validate` marks a packet (and
its views and selections) as checked, so the pipeline's guard does not
check it twice; a packet no one checked, from any source, is checked where
it enters and refused when bad. Small packets of an unpaced source are
joined before they go in, with the same output."""

from __future__ import annotations

import re

import numpy as np
import pytest

import tectum
from tectum import EventPacket, NodeError, PacketError, Pipeline, Source
from tectum.plugins.filter import BackgroundActivity
from tectum.testing import ListSink, ListSource, assert_streams_equal, feed


def events(n: int = 50, sensor: tuple[int, int] = (16, 12)) -> EventPacket:
    rng = np.random.default_rng(0)
    return EventPacket(np.arange(n, dtype=np.int64) * 10, rng.integers(0, sensor[0], n).astype(np.uint16),
                       rng.integers(0, sensor[1], n).astype(np.uint16), np.where(np.arange(n) % 2, 1, -1).astype(np.int8),
                       sensor=sensor, t_start=0, t_end=n * 10)


class Untrusted(Source):
    """Yields the packets it is given, as built: nobody validated them."""

    name = "untrusted_test"

    def __init__(self, packets: list[EventPacket]) -> None:
        self._packets = packets

    def packets(self):  # type: ignore[no-untyped-def]
        yield from self._packets


def run_source(source: Source, **batch: int) -> ListSink:
    sink = ListSink()
    p = Pipeline(**batch)
    p.sink(sink, p.source(source, id="cam"), id="out")
    tectum.run(p)
    return sink


@pytest.mark.parametrize("column, value, message", [
    ("x", 16, "event 1 has x=16, outside the sensor 16x12"),  # event 7 is the 2nd of its piece
    ("y", 200, "event 1 has y=200, outside the sensor 16x12"),
    ("p", 0, "event 1 has polarity 0, expected"),
    ("t", 5, "timestamps decrease|outside the packet interval"),
])
def test_a_bad_packet_from_an_untrusted_source_is_refused(column, value, message):
    good = events()
    arrays = {k: getattr(good, k).copy() for k in ("t", "x", "y", "p")}
    arrays[column][7] = value
    bad = EventPacket(*(arrays[k] for k in ("t", "x", "y", "p")), sensor=good.sensor, t_start=0, t_end=good.t_end)
    # cut into small views, as a reader would: views of an unchecked packet are unchecked
    pieces = [bad.slice_time(a, a + 30) for a in range(0, bad.t_end, 30)]
    assert not any(q.checked for q in pieces)
    with pytest.raises(NodeError, match="cam") as err:
        run_source(Untrusted([good.slice_time(None, 0), *pieces]))
    cause = err.value.__cause__
    assert isinstance(cause, PacketError) and "source 'cam'" in str(cause)
    assert re.search(message, str(cause))


def test_validate_marks_the_packet_and_its_views_checked():
    ev = events()
    assert not ev.checked and not ev.slice_time(0, 100).checked
    assert ev.validate() is ev and ev.checked
    assert ev.slice_time(0, 100).checked and ev.select(ev.p > 0).checked
    assert all(q.checked for q in ev.batches(7))
    assert ev.with_columns(v=np.zeros(len(ev))).checked
    assert not EventPacket(ev.t, ev.x, ev.y, ev.p, sensor=ev.sensor).checked  # built anew: unchecked


def test_the_guard_checks_a_checked_packet_once(monkeypatch):
    import tectum._packet as packet_module

    calls = []
    real = packet_module._events_ok
    monkeypatch.setattr(packet_module, "_events_ok", lambda *a: calls.append(1) or real(*a))
    ev = events()
    run_source(ListSource([ev.validate()]))
    assert len(calls) == 1  # by validate(), not again by the guard
    run_source(Untrusted([events()]))
    assert len(calls) == 2  # an unchecked packet: by the guard


def test_small_packets_are_joined_with_the_same_output():
    ev = events(2000, (32, 24)).validate()
    pieces = [ev.slice_time(a, a + 50) for a in range(0, ev.t_end, 50)]
    sink = ListSink()
    p = Pipeline()
    p.sink(sink, p.op(BackgroundActivity(dt_us=200), p.source(ListSource(pieces), id="cam"), id="ba"), id="out")
    stats = tectum.run(p)
    assert stats.nodes["ba"].packets_in < len(pieces) / 10  # joined
    assert stats.nodes["cam"].events_out == len(ev)
    assert_streams_equal(feed(BackgroundActivity(dt_us=200), pieces), sink.packets)
    one = run_source(ListSource(pieces), max_events=1)  # event by event: never joined
    assert len(one.packets) == len(np.unique(ev.t))
