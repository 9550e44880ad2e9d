"""Sample streams written by the CSV, TUM and PLY sinks read back exactly
(every built-in kind with flat fields, random values and splits); the
sinks are atomic, keep one layout per file and refuse what they cannot
store."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sample_streams import FLAT_KINDS, sample_packet, splits

from tectum import EventPacket, ImuPacket, Kind, MapPacket, PointPacket, PosePacket, TrackPacket
from tectum.sinks.files import SAMPLE_SINKS
from tectum.sinks.files._common import write_all
from tectum.sinks.files.ply import PlySink
from tectum.sinks.files.samples_csv import CsvSink
from tectum.sinks.files.tum import TumSink
from tectum.sources.files import open_file
from tectum.testing import assert_streams_equal

SETTINGS = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _read(path: Path, **kw: object) -> list:
    return list(open_file(str(path), **kw).packets())


@pytest.mark.parametrize("kind", FLAT_KINDS, ids=str)
@SETTINGS
@given(data=st.data(), cuts=st.lists(st.integers(0, 40), max_size=4))
def test_csv_round_trip_is_exact(kind: Kind, data: st.DataObject, cuts: list[int], tmp_path_factory) -> None:
    pkt = data.draw(sample_packet(kind, extras=data.draw(st.booleans())))
    f = tmp_path_factory.mktemp("csv") / "s.csv"
    write_all(CsvSink(str(f)), splits(pkt, cuts))
    got = _read(f)
    assert {q.kind for q in got} <= {kind}
    assert_streams_equal([pkt], got, f"{kind} via csv")
    if len(pkt):
        assert all(got[0].data[k].dtype == v.dtype for k, v in pkt.data.items())


@SETTINGS
@given(data=st.data(), cuts=st.lists(st.integers(0, 40), max_size=4))
def test_tum_round_trip_is_exact(data: st.DataObject, cuts: list[int], tmp_path_factory) -> None:
    pkt = data.draw(sample_packet(Kind.POSES, keep=("position", "orientation"), max_rows=60))
    f = tmp_path_factory.mktemp("tum") / "s.tum"
    write_all(TumSink(str(f)), splits(pkt, cuts))
    assert_streams_equal([pkt], _read(f), "tum")


@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "binary"])
@SETTINGS
@given(data=st.data(), cuts=st.lists(st.integers(0, 40), max_size=4))
def test_ply_round_trip_is_exact(binary: bool, data: st.DataObject, cuts: list[int], tmp_path_factory) -> None:
    pkt = data.draw(sample_packet(Kind.POINTS, t_max=1 << 53))
    f = tmp_path_factory.mktemp("ply") / "s.ply"
    write_all(PlySink(str(f), binary=binary), splits(pkt, cuts))
    assert_streams_equal([pkt], _read(f), "ply")


def test_tum_text_is_the_format(tmp_path: Path) -> None:
    """Seconds with 6 decimals (the exact µs, negative times too), the other
    numbers in the fewest digits that read back to the same float64."""
    pkt = PosePacket([-1, 1_403_636_579_763_556], position=[[0.1, -2.5, 1e-300], [3.0, 0.0, -0.0]],
                     orientation=[[0, 0, 0, 1.0], [0.5, 0.5, 0.5, 0.5]])
    f = tmp_path / "a.tum"
    write_all(TumSink(str(f)), [pkt])
    assert f.read_text().splitlines() == ["# t[s] tx ty tz qx qy qz qw",
                                          "-0.000001 0.1 -2.5 1e-300 0.0 0.0 0.0 1.0",
                                          "1403636579.763556 3.0 0.0 -0.0 0.5 0.5 0.5 0.5"]


def test_tum_leaves_out_lost_rows_and_counts_them_csv_keeps_them(tmp_path: Path) -> None:
    """A tracker's ``lost`` rows are predictions: TUM (which has no column
    for the flag) leaves them out and counts them as not written; CSV keeps
    every row with the flag."""
    q = np.tile([0, 0, 0, 1.0], (4, 1))
    pkt = PosePacket([1, 2, 3, 4], position=np.arange(12.0).reshape(4, 3), orientation=q,
                     lost=np.array([False, True, True, False]))
    sink = TumSink(str(tmp_path / "a.tum"))
    write_all(sink, [pkt.take(np.arange(2)), pkt.take(np.arange(2, 4))])
    assert sink.not_written == {"poses": 2} and sink.rows == 2
    kept = pkt.take(np.array([0, 3]))
    assert_streams_equal([PosePacket(kept.t, position=kept.position, orientation=kept.orientation)],
                         _read(tmp_path / "a.tum"), "tum")
    write_all(CsvSink(str(tmp_path / "a.csv")), [pkt])
    assert_streams_equal([pkt], _read(tmp_path / "a.csv"), "csv")


def test_csv_text_is_the_format(tmp_path: Path) -> None:
    pkt = TrackPacket([10, 10, 25], id=[1, 2, -(1 << 63)], x=[0.5, 1.0, np.nan], y=[2.0, np.inf, 3.25],
                      age=np.array([7, 8, 9], np.int32))
    f = tmp_path / "t.csv"
    write_all(CsvSink(str(f)), [pkt])
    assert f.read_text().splitlines() == ["# tectum tracks age=int32", "t,id,x,y,age", "10,1,0.5,2.0,7",
                                          "10,2,1.0,inf,8", f"25,{-(1 << 63)},nan,3.25,9"]


def test_csv_writes_the_first_sample_kind_or_the_one_named(tmp_path: Path) -> None:
    ev = EventPacket.from_arrays([1, 2], [0, 1], [0, 1], [1, -1], sensor=(4, 4), t_end=50)
    imu = ImuPacket([5, 9], accel=np.ones((2, 3)), gyro=np.zeros((2, 3)))
    poses = PosePacket([7], position=[[1.0, 2, 3]], orientation=[[0, 0, 0, 1.0]])
    stream = [ev, imu, poses, ev.slice_time(60, 70)]
    first = tmp_path / "first.csv"
    write_all(CsvSink(str(first)), stream)
    assert_streams_equal([imu], _read(first))
    named = tmp_path / "named.csv"
    write_all(CsvSink(str(named), kind="poses"), stream)
    assert_streams_equal([poses], _read(named))
    events = tmp_path / "events.csv"  # events alone: the RPG CSV layout, read by the text source
    write_all(CsvSink(str(events)), [ev])
    assert events.read_text().splitlines()[0] == "t,x,y,p"
    assert_streams_equal([ev], [q for q in _read(events, sensor="4x4") if q.kind == Kind.EVENTS])
    assert sorted(os.listdir(tmp_path)) == ["events.csv", "first.csv", "named.csv"]  # no temporary file left
    for kind in ("frames", "maps"):
        with pytest.raises(ValueError, match="frames and maps go to .npz"):
            CsvSink(str(tmp_path / "f.csv"), kind=kind)


def test_a_csv_after_a_mapper_holds_the_flat_stream_and_counts_the_maps(tmp_path: Path) -> None:
    """Maps (all-optional image fields) are not a table's stream: a CSV sink
    fed maps and poses holds the poses, chosen when the pipeline is
    validated, and counts the maps as not written (it failed after the run)."""
    import tectum
    from tectum.testing import ListSource

    img = np.zeros((1, 6, 8), np.float32)
    maps = [MapPacket([t], image=img, depth=img + 1.0, t_start=t, t_end=t + 10) for t in (0, 10)]
    poses = PosePacket([3, 13], position=np.zeros((2, 3)), orientation=[[0, 0, 0, 1.0]] * 2, t_start=0, t_end=20)
    p = tectum.Pipeline()
    out = tmp_path / "out.csv"
    p.sink(str(out), p.source(ListSource([maps[0], poses, maps[1]])), id="csv")
    stats = tectum.run(p)
    assert_streams_equal([poses], _read(out))
    assert stats.nodes["csv"].not_written == {"maps": 2}
    p = tectum.Pipeline()  # maps alone: refused before the run, naming the node
    p.sink(str(tmp_path / "maps.csv"), p.source(ListSource(maps)), id="csv")
    with pytest.raises(tectum.PipelineError, match=r"node 'csv' .*its input provides only maps: a CSV holds events"):
        p.validate()
    assert not (tmp_path / "maps.csv").exists()


@pytest.mark.parametrize("cls", SAMPLE_SINKS, ids=lambda c: c.name)
def test_abort_leaves_nothing(cls: type, tmp_path: Path) -> None:
    f = tmp_path / ("o" + cls.extensions[0])
    s = cls(str(f))
    s.open()
    s.write(PosePacket([1, 2], position=np.zeros((2, 3)), orientation=[[0, 0, 0, 1.0]] * 2))
    s.write(PointPacket([3], position=np.zeros((1, 3))))
    s.abort()
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("cls", SAMPLE_SINKS, ids=lambda c: c.name)
def test_an_empty_stream_is_a_valid_empty_file(cls: type, tmp_path: Path) -> None:
    f = tmp_path / ("o" + cls.extensions[0])
    write_all(cls(str(f)), [])
    assert all(len(q) == 0 for q in _read(f, sensor="4x4"))


def test_an_optional_float_field_missing_later_is_nan_a_new_one_is_refused(tmp_path: Path) -> None:
    a = TrackPacket([1, 2], id=[1, 2], x=[0.0, 1], y=[0.0, 1], quality=[0.5, 0.25])
    b = TrackPacket([3], id=[3], x=[2.0], y=[2.0])
    f = tmp_path / "t.csv"
    write_all(CsvSink(str(f)), [a, b])
    got = _read(f)
    assert np.array_equal(np.concatenate([q.quality for q in got]), [0.5, 0.25, np.nan], equal_nan=True)
    later = TrackPacket([4, 5], id=[1, 2], x=[0.0, 1], y=[0.0, 1], quality=[1.0, 2])
    with pytest.raises(ValueError, match=r"\['quality'\] first appear at t=4"):
        write_all(CsvSink(str(tmp_path / "u.csv")), [b, later])
    wider = TrackPacket([6], id=[5], x=[0.0], y=[0.0], quality=[1.0], age=np.array([1], np.int64))
    with pytest.raises(ValueError, match="field 'age' changes from int32 to int64"):
        write_all(CsvSink(str(tmp_path / "v.csv")), [TrackPacket([1], id=[1], x=[0.0], y=[0.0], quality=[1.0],
                                                                 age=np.array([1], np.int32)), wider])
    assert sorted(os.listdir(tmp_path)) == ["t.csv"]


def test_ply_refuses_what_it_cannot_store(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="'label'.*no place"):
        write_all(PlySink(str(tmp_path / "a.ply")), [PointPacket([1], position=np.zeros((1, 3)), label=[3])])
    with pytest.raises(ValueError, match="2\\*\\*53"):
        write_all(PlySink(str(tmp_path / "b.ply")), [PointPacket([(1 << 53) + 1], position=np.zeros((1, 3)))])
    assert os.listdir(tmp_path) == []
