"""The .npz source and sink: exact round trips, chunking, bad files."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum import EventPacket, FormatError, concat
from tectum.sinks.npz import NpzSink, write_npz
from tectum.sources.npz import NpzSource, read_npz
from tectum.testing import assert_stream_contract, assert_streams_equal

from helpers import bars


def test_round_trip_keeps_every_column_and_the_interval(tmp_path):
    pk = bars(20_000)
    f = tmp_path / "a.npz"
    write_npz(str(f), pk)
    back = read_npz(str(f))
    assert back.column_names == pk.column_names and back.sensor == pk.sensor
    assert (back.t_start, back.t_end) == (pk.t_start, pk.t_end)
    assert_streams_equal([pk], [back])
    raw = np.load(f)  # plain numpy reads it too
    assert np.array_equal(raw["t"], pk.t) and raw["sensor"].tolist() == list(pk.sensor)


@settings(max_examples=15, deadline=None)
@given(chunk=st.integers(1, 300), repeat=st.integers(1, 4))
def test_chunks_never_split_a_timestamp(tmp_path_factory, chunk, repeat):
    t = np.repeat(np.arange(0, 400, 3), repeat)
    n = len(t)
    pk = EventPacket.from_arrays(t, np.arange(n) % 7, np.zeros(n), np.ones(n), sensor=(8, 2), t_end=500)
    f = tmp_path_factory.mktemp("c") / "c.npz"
    write_npz(str(f), pk)
    parts = list(NpzSource(str(f), chunk_events=chunk).packets())
    assert_stream_contract(parts)
    assert_streams_equal([pk], parts)
    assert parts[-1].t_end == 500


def test_foreign_npz_with_seconds_and_01_polarity(tmp_path):
    f = tmp_path / "foreign.npz"
    np.savez(f, t=np.array([0.5, 0.75]), x=np.array([3, 9]), y=np.array([1, 2]), p=np.array([0, 1]))
    with pytest.raises(FormatError, match="floating point"):
        read_npz(str(f))
    pk = read_npz(str(f), time_unit="s")
    assert pk.t.tolist() == [500000, 750000] and pk.p.tolist() == [-1, 1] and pk.sensor == (10, 3)
    assert read_npz(str(f), time_unit="s", sensor="20x10").sensor == (20, 10)


def test_bad_files_say_what_is_wrong(tmp_path):
    f = tmp_path / "bad.npz"
    f.write_bytes(b"not a zip at all")
    with pytest.raises(FormatError, match="bad.npz: not a readable .npz"):
        read_npz(str(f))
    np.savez(f, t=np.arange(3), x=np.arange(3))
    with pytest.raises(FormatError, match=r"missing column\(s\) \['y', 'p'\]"):
        read_npz(str(f))
    np.savez(f, t=np.arange(3), x=np.arange(3), y=np.arange(2), p=np.ones(3))
    with pytest.raises(FormatError, match="column 'y' has shape"):
        read_npz(str(f))
    good = tmp_path / "good.npz"
    write_npz(str(good), bars(5000))
    data = good.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError):
        read_npz(str(tmp_path / "cut.npz"))


def test_sink_is_atomic_and_streams(tmp_path):
    f = tmp_path / "out.npz"
    s = NpzSink(str(f))
    s.open()
    pk = bars(20_000)
    for piece in pk.batches(97):
        s.write(piece)
    assert not f.exists()  # nothing visible until close
    s.close()
    assert_streams_equal([pk], [read_npz(str(f))])
    s2 = NpzSink(str(tmp_path / "aborted.npz"))
    s2.open()
    s2.write(pk)
    s2.abort()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.npz"]
    with zipfile.ZipFile(f) as zf:
        assert {"t.npy", "x.npy", "y.npy", "p.npy", "noise.npy", "vx.npy", "vy.npy", "sensor.npy", "interval.npy"} == set(zf.namelist())


def test_empty_stream_writes_a_valid_file(tmp_path):
    f = tmp_path / "empty.npz"
    s = NpzSink(str(f))
    s.open()
    s.close()
    assert len(concat(list(NpzSource(str(f), sensor="4x4").packets()) or [EventPacket.empty((4, 4), 0)])) == 0
