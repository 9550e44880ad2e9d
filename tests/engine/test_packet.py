"""The packet contract: dtypes, intervals, zero-copy views, concatenation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import tectum
from tectum import EventPacket, ImuPacket, PacketError, ResultPacket, concat, from_structured, to_structured
from tectum.testing import assert_stream_contract


def make(t, sensor=(10, 10), **kw):
    t = np.asarray(t, np.int64)
    n = len(t)
    return EventPacket(t, np.arange(n, dtype=np.uint16) % sensor[0], np.zeros(n, np.uint16),
                       np.ones(n, np.int8), sensor=sensor, **kw)


def test_dtypes_are_strict():
    with pytest.raises(PacketError, match="'t' must be a 1-D int64"):
        EventPacket(np.zeros(2, np.int32), np.zeros(2, np.uint16), np.zeros(2, np.uint16),
                    np.ones(2, np.int8), sensor=(4, 4))
    with pytest.raises(PacketError, match="'y' has 1 events"):
        EventPacket(np.zeros(2, np.int64), np.zeros(2, np.uint16), np.zeros(1, np.uint16),
                    np.ones(2, np.int8), sensor=(4, 4))


def test_from_arrays_converts_polarity_and_dtypes():
    pk = EventPacket.from_arrays([1, 2, 3], [0, 1, 2], [3, 2, 1], [0, 1, 0], sensor=(4, 4))
    assert pk.p.tolist() == [-1, 1, -1] and pk.x.dtype == np.uint16 and pk.t.dtype == np.int64
    assert (pk.t_start, pk.t_end) == (1, 4)
    with pytest.raises(PacketError, match="mixes 0 with -1"):
        EventPacket.from_arrays([1, 2, 3], [0, 0, 0], [0, 0, 0], [0, 1, -1], sensor=(4, 4))


@pytest.mark.parametrize(
    "kw, message",
    [
        (dict(t=[3, 2]), "timestamps decrease at index 1"),
        (dict(x=[0, 9]), "event 1 has x=9, outside the sensor 4x4"),
        (dict(t_end=2), "outside the packet interval"),
    ],
)
@pytest.mark.abuse
def test_validate_names_the_bad_event(kw, message):
    t = kw.pop("t", [1, 2])
    x = kw.pop("x", [0, 1])
    pk = EventPacket.from_arrays(t, x, [0, 0], [1, 1], sensor=(4, 4), validate=False,
                                 t_start=0, t_end=kw.pop("t_end", 10))
    with pytest.raises(PacketError, match=message):
        pk.validate()


def test_empty_packet_carries_its_interval():
    pk = EventPacket.empty((4, 4), 100, 200)
    assert len(pk) == 0 and (pk.t_start, pk.t_end) == (100, 200)
    assert pk.validate() is pk


def test_slice_time_is_a_view_with_clipped_interval():
    pk = make([10, 20, 20, 30, 40], t_start=5, t_end=50)
    s = pk.slice_time(20, 35)
    assert s.t.tolist() == [20, 20, 30] and (s.t_start, s.t_end) == (20, 35)
    assert np.shares_memory(s.t, pk.t) and np.shares_memory(s.x, pk.x)
    assert (pk.slice_time(0, 100).t_start, pk.slice_time(0, 100).t_end) == (5, 50)


def test_extra_columns_share_the_base_arrays():
    pk = make([1, 2, 3])
    vx = np.array([1.0, 2.0, 3.0])
    q = pk.with_columns(vx=vx)
    assert q.t is pk.t and q["vx"] is vx and q.column_names == ("t", "x", "y", "p", "vx")
    assert q.slice_time(2, 3)["vx"].tolist() == [2.0]
    with pytest.raises(PacketError, match="expected 3 rows"):
        pk.with_columns(bad=np.zeros(2))
    assert "vx" not in q.without_columns("vx").columns


def test_packets_are_immutable():
    pk = make([1])
    with pytest.raises(AttributeError):
        pk.t = np.zeros(1, np.int64)  # type: ignore[misc]


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 50), min_size=1, max_size=60).map(sorted), st.integers(1, 7))
def test_batches_tile_the_interval_and_keep_equal_timestamps_together(ts, k):
    pk = make(ts, t_start=0, t_end=60)
    parts = list(pk.batches(k))
    assert parts[0].t_start == 0 and parts[-1].t_end == 60
    assert_stream_contract(parts)
    for q in parts:
        assert len(q) <= k or len(np.unique(q.t)) == 1
    back = concat(parts)
    assert back.t.tolist() == ts and (back.t_start, back.t_end) == (0, 60)


def test_concat_checks_order_sensor_and_columns():
    a, b = make([1, 2], t_start=0, t_end=3), make([3, 4], t_start=3, t_end=5)
    assert concat([a, b]).t.tolist() == [1, 2, 3, 4]
    with pytest.raises(PacketError, match="overlap"):
        concat([b, a])
    with pytest.raises(PacketError, match="sensor sizes differ"):
        concat([a, make([5], sensor=(20, 20), t_start=5)])
    with pytest.raises(PacketError, match="extra columns differ"):
        concat([a, b.with_columns(vx=np.zeros(2))])


def test_sample_packets():
    imu = ImuPacket([1, 2, 3], accel=np.zeros((3, 3)), gyro=np.ones((3, 3)), t_end=10)
    assert imu.gyro.shape == (3, 3) and imu.kind == "imu"
    s = imu.slice_time(2, 10)
    assert len(s) == 2 and np.shares_memory(s.gyro, imu.gyro)
    with pytest.raises(PacketError, match="needs fields"):
        ImuPacket([1], accel=np.zeros((1, 3)))
    with pytest.raises(PacketError, match="timestamps decrease"):
        ImuPacket([2, 1], accel=np.zeros((2, 3)), gyro=np.zeros((2, 3)))
    tick = ImuPacket.empty(5, 9, like=imu)
    assert len(tick) == 0 and tick.gyro.shape == (0, 3) and tick.gyro.dtype == imu.gyro.dtype
    r = concat([ResultPacket([1], [{"a": 1}], t_end=5), ResultPacket([7], [[1, 2]], t_start=5, t_end=9)])
    assert r.items.tolist() == [{"a": 1}, [1, 2]]


@pytest.mark.parametrize("layout", ["tonic", "faery", "metavision", "dv"])
def test_structured_adapters_round_trip(layout):
    pk = EventPacket.from_arrays([5, 6, 9], [1, 2, 3], [0, 3, 2], [1, -1, 1], sensor=(4, 4))
    arr = to_structured(pk, layout)
    back = from_structured(arr, sensor=(4, 4))
    for c in "txyp":
        assert np.array_equal(back[c], pk[c]), c


def test_from_structured_seconds():
    arr = np.array([(0.5, 1, 1, 1)], dtype=[("t", "f8"), ("x", "u2"), ("y", "u2"), ("p", "u1")])
    assert from_structured(arr, sensor=(2, 2), time_scale=1e6).t.tolist() == [500000]


@pytest.mark.parametrize("t, message", [
    ([0.0, float("nan"), 2.0], "sample 1 has t=nan"),
    ([float("inf")], "sample 0 has t=inf"),
    ([1e30], "sample 0"),
    ([0.5, 1.0], "whole µs"),
])
@pytest.mark.abuse
def test_non_finite_or_fractional_times_are_rejected(t, message):
    """Regression: NaN/inf/1e30 became INT64_MIN, 0.5 s truncated to 0."""
    with pytest.raises(tectum.PacketError, match=message):
        tectum.EventPacket.from_arrays(t, [0] * len(t), [0] * len(t), [1] * len(t), sensor=(4, 4))


@pytest.mark.abuse
def test_seconds_only_when_asked():
    pkt = tectum.EventPacket.from_arrays([0.5, 1.0000015], [0, 1], [0, 0], [1, 0], sensor=(4, 4), time_unit="s")
    assert pkt.t.tolist() == [500_000, 1_000_002]


@pytest.mark.abuse
def test_nan_coordinates_are_rejected_not_zeroed():
    with pytest.raises(tectum.PacketError, match="event 1 has x=nan"):
        tectum.EventPacket.from_arrays([0, 1], [0.0, float("nan")], [0, 0], [1, 1], sensor=(4, 4))


@pytest.mark.abuse
def test_unsorted_times_name_the_first_decreasing_index():
    with pytest.raises(tectum.PacketError, match="timestamps decrease at index 2: 30 then 21"):
        tectum.EventPacket.from_arrays([20, 30, 21], [0, 0, 0], [0, 0, 0], [1, 1, 1], sensor=(4, 4))
